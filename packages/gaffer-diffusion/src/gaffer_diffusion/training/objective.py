"""The training objective of one micro-batch (official implementation §3, steps 2-5 of `loop`).

`TrainingObjective.loss` takes a micro-batch to its loss: lighting maps rotated and encoded (or the
authors' pre-encoded ones), optional mirroring, one VAE call for inputs, maps and targets, CLIP of the
inputs, the forward process at a random timestep, CFG dropout, and the UNet's regression loss.
Randomness comes only from the per-sample generators it is given (`ItemRandom`).
"""

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.conditioning import clip_preprocess
from gaffer_diffusion.configs import ModelConfig
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.geometry import input_normals
from gaffer_diffusion.hints import hints_at
from gaffer_diffusion.models.build import build_scheduler
from gaffer_diffusion.models.model import NeuralGafferModel, vae_decode, vae_posterior
from gaffer_diffusion.models.pixel import PixelPosterior
from gaffer_diffusion.training.batch import TrainBatch
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.lighting import batch_lighting_of


def sample_generator(seed: int, position: int) -> torch.Generator:
    """The generator of the sample at `position` of the run's data stream (counted over all
    processes, as `KeySampler` counts): a function of (seed, position) only."""
    state = np.random.SeedSequence([seed, position]).generate_state(2, dtype=np.uint64)
    return torch.Generator().manual_seed(int(state[0]) & 0x7FFF_FFFF_FFFF_FFFF)


class ItemRandom:
    """The random streams of one micro-batch, one generator per sample.

    Sample i's noise, timesteps, CFG-dropout draws, posterior sample and mirror flip come from its own
    generator (`sample_generator(seed, position_i)`), so they do not depend on how the global batch is
    split over processes and micro-batches: 2 processes of batch B train exactly as 1 process of
    batch 2B (up to float rounding), and `--resume` may change the process count.
    Every draw takes `per_item` values from each generator in turn and concatenates them, item-major.
    """

    def __init__(self, generators: Sequence[torch.Generator]) -> None:
        self.generators = tuple(generators)

    @classmethod
    def for_positions(cls, seed: int, positions: Sequence[int]) -> "ItemRandom":
        """One `sample_generator` per data-stream position."""
        return cls([sample_generator(seed, p) for p in positions])

    def __len__(self) -> int:
        return len(self.generators)

    def rand(self, *per_item: int) -> Tensor:
        """U[0, 1) draws, `[len(self) * per_item[0], *per_item[1:]]`."""
        return torch.cat([torch.rand(per_item, generator=g) for g in self.generators])

    def randn(self, *per_item: int) -> Tensor:
        """N(0, 1) draws, `[len(self) * per_item[0], *per_item[1:]]`."""
        return torch.cat([torch.randn(per_item, generator=g) for g in self.generators])

    def randint(self, low: int, high: int, per_item: int) -> Tensor:
        """Integers in [low, high), `[len(self) * per_item]`."""
        return torch.cat(
            [torch.randint(low, high, (per_item,), generator=g) for g in self.generators]
        )


def _posterior_sample(posterior: Any, eps: Tensor) -> Tensor:
    """A draw of the VAE posterior with the given standard normal `eps` (the pixel autoencoder's
    posterior has no noise: its latent)."""
    if isinstance(posterior, PixelPosterior):
        return posterior.sample()
    return posterior.mean + posterior.std * eps.to(posterior.mean)


def cfg_dropout_masks(r: torch.Tensor, p: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The paper's CFG dropout from one uniform draw per item (official implementation §2).

    Returns:
        `(drop_clip, drop_latents)` bool `[N]`: r < 2p drops the CLIP embedding, p <= r < 3p drops the
        three conditioning latents (so 5% / 5% / 5% CLIP only / both / latents only for p = 0.05).

    Example:
        >>> c, l = cfg_dropout_masks(torch.tensor([0.01, 0.07, 0.12, 0.5]), 0.05)
        >>> c.tolist(), l.tolist()
        ([True, True, False, False], [False, True, True, False])
    """
    return r < 2 * p, (r >= p) & (r < 3 * p)


class TrainingObjective:
    """The loss of one micro-batch, with what it needs from the model (schedule, frozen-network dtype)."""

    def __init__(self, config: TrainConfig, accelerator: Any, model: NeuralGafferModel) -> None:
        self.cfg = config
        self.acc = accelerator
        self.model = model
        self.device = accelerator.device
        self.scheduler = build_scheduler(model.config.scheduler)
        n_train = int(self.scheduler.config["num_train_timesteps"])
        if config.train.timestep_range[1] >= n_train:
            raise ConfigError(
                f"`train.timestep_range` is {list(config.train.timestep_range)}; the model's schedule "
                f"has {n_train} timesteps, so hi must be <= {n_train - 1}."
            )
        if config.train.residual_loss_floor is not None and not model.config.residual:
            raise ConfigError(
                "`train.residual_loss_floor` is set but the model diffuses the target itself "
                "(`ModelConfig.residual` false); remove it, or train a residual model."
            )
        if config.train.loss_space == "display_object":
            _check_display_object(model.config, self.scheduler.config["prediction_type"])
        self.alphas_cumprod = self.scheduler.alphas_cumprod.to(self.device)
        cuda = self.device.type == "cuda"
        mp = config.train.mixed_precision
        # frozen networks in half precision only on GPUs (CPU half kernels are slow or missing)
        self.weight_dtype = (
            {
                "fp16": torch.float16,
                "bf16": torch.bfloat16,
                "no": torch.float32,
            }[mp]
            if cuda
            else torch.float32
        )

    # ---------------------------------------------------------------- one micro-step
    def loss(self, unet: torch.nn.Module, batch: TrainBatch, gen: ItemRandom) -> torch.Tensor:
        """The MSE of one micro-batch against the scheduler's `prediction_type` target (epsilon by
        default; see the module docstring and `_prediction_target`); `gen` has one generator per
        sample of the batch."""
        cfg, dev, m = self.cfg, self.device, self.model
        b, t = batch.batch_size, batch.targets_per_sample
        n = b * t
        if len(gen) != b:
            raise ValueError(f"{len(gen)} sample generators for a batch of {b}")
        res = m.config.resolution
        inputs = batch.input_images.to(dev, non_blocking=True)  # [B, 3, H, W]
        targets = batch.target_images.to(dev, non_blocking=True).flatten(0, 1)  # [BT, 3, H, W]
        # environment maps rotated + encoded here; the authors' pre-encoded maps used as they are
        ldr, hdr = batch_lighting_of(
            batch, size=res, compat=cfg.data.lighting_compat, device=dev
        )  # [BT, 3, H, W] each, camera frame, in [0, 1]
        alphas = None
        if m.config.hints:
            if batch.input_alphas is None:
                raise ConfigError(
                    "the model takes radiance hints (`ModelConfig.hints`), which need each input's "
                    "object mask, but this dataset's items have no alpha; train on gaffer-data renders."
                )
            alphas = batch.input_alphas.to(dev, non_blocking=True)  # [B, 1, H, W]
        if cfg.data.mirror_prob > 0:
            inputs, targets, ldr, hdr, alphas = _mirror_views(
                inputs, targets, ldr, hdr, t, cfg.data.mirror_prob, gen, alphas
            )
        with torch.no_grad():
            # [B + 3BT, 3, H, W]  inputs, HDR maps, LDR maps, targets in one VAE call, [0,1] -> [-1,1]
            stacked = torch.cat([inputs, hdr, ldr, targets]) * 2.0 - 1.0
            posterior = vae_posterior(m.vae, stacked.to(self.weight_dtype))
            # each sample's posterior noise from its own generator, in the stack's row order
            eps = gen.randn(1 + 3 * t, *posterior.mode().shape[1:]).view(b, 1 + 3 * t, -1)
            eps = torch.cat(
                [eps[:, 0], *(eps[:, 1 + k * t : 1 + (k + 1) * t].flatten(0, 1) for k in range(3))]
            ).view(posterior.mode().shape)
            sampled = _posterior_sample(posterior, eps).float()
            cond_all = posterior.mode().float() if cfg.train.cond_latent_mode == "mode" else sampled
            image_lat = cond_all[:b].repeat_interleave(t, dim=0)  # [BT, 4, h, w] raw latents
            hdr_lat = cond_all[b : b + n]
            ldr_lat = cond_all[b + n : b + 2 * n]
            # only the target latent is scaled (official implementation §1); residual models
            # diffuse target - input (`ModelConfig.residual`)
            z0 = m.diffusion_target(sampled[b + 2 * n :], image_lat)  # [BT, 4, h, w]
            pixels = clip_preprocess(
                inputs.to(self.weight_dtype) * 2.0 - 1.0, m.config.image_encoder.image_size
            )
            clip = (
                m.image_encoder(pixel_values=pixels).image_embeds.float().unsqueeze(1)
            )  # [B, 1, D]
            clip = clip.repeat_interleave(t, dim=0)  # [BT, 1, D]
            parts = [image_lat, hdr_lat, ldr_lat]
            mask = None
            if alphas is not None:  # radiance hints of the (possibly mirrored) inputs' masks
                mask = alphas.repeat_interleave(t, dim=0)
                geometry = m.config.hint_geometry
                images = normals = None
                if geometry == "estimated":
                    # the estimator once per input, not once per target (the targets share their input)
                    normals = input_normals(geometry, inputs, alphas).repeat_interleave(t, dim=0)
                    images = inputs.repeat_interleave(t, dim=0)
                parts.append(
                    hints_at(
                        mask,
                        ldr,
                        hdr,
                        int(image_lat.shape[-1]),
                        geometry=geometry,
                        image=images,
                        normals=normals,
                    )
                )
        cond = torch.cat(parts, dim=1)  # [BT, 12 (+12 hints), h, w]
        noise = gen.randn(t, *z0.shape[1:]).to(dev)  # rows item-major, as z0's
        lo, hi = cfg.train.timestep_range  # checked against the schedule at start-up
        timesteps = gen.randint(lo, hi + 1, t).to(dev)
        r = gen.rand(t).to(dev)
        drop_clip, drop_lat = cfg_dropout_masks(r, cfg.train.cfg_dropout_p)
        clip = clip * (~drop_clip).to(clip.dtype).view(n, 1, 1)
        cond = cond * (~drop_lat).to(cond.dtype).view(n, 1, 1, 1)
        abar = self.alphas_cumprod[timesteps].float().view(n, 1, 1, 1)
        z_t = abar.sqrt() * z0 + (1.0 - abar).sqrt() * noise  # forward process q(z_t | z_0)
        with self.acc.autocast():
            # [BT, 16 (+12), h, w]  z_t + 3x4 conditioning latents (+ hints)
            pred = unet(torch.cat([z_t, cond], dim=1), timesteps, encoder_hidden_states=clip).sample
        if cfg.train.loss_space == "display_object":
            z0_pred = _predicted_z0(m.config.scheduler.prediction_type, pred.float(), z_t, abar)
            image_pred = vae_decode(m.vae, m.decodable_latents(z0_pred, image_lat))  # [-1, 1]
            weight = mask if mask is not None else torch.ones_like(targets[:, :1])
            return display_object_loss(image_pred, targets * 2.0 - 1.0, weight)
        target = _prediction_target(m.config.scheduler.prediction_type, z0, noise, abar)
        return diffusion_loss(pred.float(), target, z0, cfg.train.residual_loss_floor)


def _mirror_views(
    inputs: Float[Tensor, "B 3 H W"],
    targets: Float[Tensor, "BT 3 H W"],
    ldr: Float[Tensor, "BT 3 H W"],
    hdr: Float[Tensor, "BT 3 H W"],
    targets_per_view: int,
    prob: float,
    gen: torch.Generator | ItemRandom,
    alphas: Float[Tensor, "B 1 H W"] | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Flip each view left-right with probability `prob`: its input (and mask), its targets and,
    mirrored in camera x, their lighting maps (`DataConfig.mirror_prob`). `gen`: one generator for
    the batch, or one per view (`ItemRandom`, as training uses)."""
    from gaffer_envmap.augment import mirror_camera_x

    b = inputs.shape[0]
    draws = gen.rand(1) if isinstance(gen, ItemRandom) else torch.rand(b, generator=gen)
    flip_view = (draws < prob).to(inputs.device)  # [B]
    flip_target = flip_view.repeat_interleave(targets_per_view).view(-1, 1, 1, 1)  # [BT,1,1,1]
    return (
        torch.where(flip_view.view(b, 1, 1, 1), inputs.flip(-1), inputs),
        torch.where(flip_target, targets.flip(-1), targets),
        torch.where(flip_target, mirror_camera_x(ldr), ldr),
        torch.where(flip_target, mirror_camera_x(hdr), hdr),
        None
        if alphas is None
        else torch.where(flip_view.view(b, 1, 1, 1), alphas.flip(-1), alphas),
    )


def diffusion_loss(
    pred: Float[Tensor, "n c h w"],
    target: Float[Tensor, "n c h w"],
    z0: Float[Tensor, "n c h w"],
    residual_loss_floor: float | None,
) -> Tensor:
    """MSE of the UNet output; with a floor c, item i weighs 1 / (mean(z0_i^2) + c), normalised
    to mean 1 (`TrainLoopConfig.residual_loss_floor`)."""
    if residual_loss_floor is None:
        return F.mse_loss(pred, target)
    weight = 1.0 / (z0.float().pow(2).mean(dim=(1, 2, 3)) + residual_loss_floor)  # [n]
    per_item = (pred - target).pow(2).mean(dim=(1, 2, 3))
    return (per_item * weight / weight.mean()).mean()


DISPLAY_LOSS_FLOOR = 1e-4
"""Added to each pair's MSE before its log (the [0, 1] scale: a 40 dB cap), so a pair that is
already almost right cannot dominate the batch."""


def display_object_loss(
    image_pred: Float[Tensor, "n 3 H W"],
    image_target: Float[Tensor, "n 3 H W"],
    alpha: Float[Tensor, "n 1 H W"],
) -> Tensor:
    """The negated mean PSNR of the pairs over their objects, raw and channel-aligned, in natural
    log units (`TrainLoopConfig.loss_space` "display_object"); images in [-1, 1], display space.

    Per pair: mean of ln(MSE_raw + f) and ln(MSE_aligned + f), MSEs alpha-weighted on the [0, 1]
    scale, f = `DISPLAY_LOSS_FLOOR`. "Aligned" scales each channel of the prediction by
    mean(target) / mean(prediction) over the object first (as the evaluation does), which removes
    exposure and tint and leaves the spatial shading: half the loss cannot be lowered by a change of
    brightness, only by moving the light. The log makes each pair count as its PSNR does in a mean
    over pairs. An item with an empty mask adds ln(f) (no gradient).
    """
    pred = (image_pred.float() + 1.0) * 0.5
    gt = (image_target.float() + 1.0) * 0.5
    w = alpha.float()
    area = w.sum(dim=(1, 2, 3)).clamp_min(1.0)  # [n]

    def masked_mse(x: Tensor) -> Tensor:
        return ((x - gt).pow(2).mean(dim=1, keepdim=True) * w).sum(dim=(1, 2, 3)) / area

    mean_pred = (pred * w).sum(dim=(2, 3), keepdim=True) / area.view(-1, 1, 1, 1)
    mean_gt = (gt * w).sum(dim=(2, 3), keepdim=True) / area.view(-1, 1, 1, 1)
    aligned = pred * (mean_gt / mean_pred.clamp_min(1e-4))
    raw_term = torch.log(masked_mse(pred) + DISPLAY_LOSS_FLOOR)
    aligned_term = torch.log(masked_mse(aligned) + DISPLAY_LOSS_FLOOR)
    return (0.5 * (raw_term + aligned_term)).mean()


def _check_display_object(model: ModelConfig, prediction_type: str) -> None:
    if model.vae.kind != "pixel" or not model.residual:
        raise ConfigError(
            "`train.loss_space` 'display_object' decodes the UNet's output at every step, which is "
            "exact and cheap only for pixel-space residual models (`vae.kind` 'pixel', "
            "`residual` true); use 'diffusion' for this model."
        )
    if prediction_type not in ("v_prediction", "sample"):
        raise ConfigError(
            f"`train.loss_space` 'display_object' needs the clean sample from the UNet's output; "
            f"the schedule predicts {prediction_type!r}; use 'v_prediction' or 'sample'."
        )


def _predicted_z0(prediction_type: str, pred: Tensor, z_t: Tensor, abar: Tensor) -> Tensor:
    """The clean sample implied by the UNet's output at `z_t` (DDIM's x0 estimate)."""
    if prediction_type == "v_prediction":
        return abar.sqrt() * z_t - (1.0 - abar).sqrt() * pred
    return pred


def _prediction_target(
    prediction_type: str, z0: torch.Tensor, noise: torch.Tensor, abar: torch.Tensor
) -> torch.Tensor:
    """What the UNet regresses: the noise ("epsilon", the paper's), the velocity
    `sqrt(abar) noise - sqrt(1 - abar) z0` ("v_prediction") or the clean latent ("sample")."""
    match prediction_type:
        case "epsilon":
            return noise
        case "v_prediction":
            return abar.sqrt() * noise - (1.0 - abar).sqrt() * z0
        case "sample":
            return z0
    raise ConfigError(
        f"`scheduler.prediction_type` is {prediction_type!r}; expected 'epsilon', 'v_prediction' "
        "or 'sample'."
    )
