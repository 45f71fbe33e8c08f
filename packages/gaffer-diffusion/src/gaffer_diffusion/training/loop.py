"""The training loop on accelerate (official implementation §3).

One optimiser step (per process, per micro-batch):

1. the data loader yields B samples, each an input view and T target views with their lighting;
2. the target lightings are rotated into the view's camera frame and split into E_L / E_H by
   gaffer-envmap, batched on the training device (no PNG round trip); items of a converted authors'
   split bring their pre-encoded E_L / E_H PNGs instead, used as they are;
3. one VAE call encodes the B inputs and the T*B HDR maps, LDR maps and targets; CLIP embeds the inputs;
4. Neural Gaffer §3.2: z_t = sqrt(abar_t) z_0 + sqrt(1 - abar_t) eps with t ~ U{0..999}, the UNet sees
   `[z_t, E(x), E(E_H), E(E_L)]` and the CLIP context; loss = ||eps - eps_theta||^2;
5. CFG dropout (InstructPix2Pix scheme, p = 0.05, one uniform r per UNet item): r < 2p zeroes the CLIP
   embedding, p <= r < 3p zeroes the three conditioning latents;
6. AdamW step (only the UNet trains), EMA update.

Randomness is a function of (seed, step, process, micro-step) and the data order of (seed, position), so
`--resume` continues with exactly the loss curve of an uninterrupted run (same process count).

Non-finite loss or gradients never reach the weights: the step is skipped and counted; after
`train.max_consecutive_nonfinite` skipped steps in a row a checkpoint is written and
`TrainingDivergedError` raised.
"""

import contextlib
import dataclasses
import logging
import math
import os
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.conditioning import clip_preprocess
from gaffer_diffusion.configs import get_preset
from gaffer_diffusion.errors import ConfigError, MissingDependencyError
from gaffer_diffusion.hints import hints_at
from gaffer_diffusion.models.build import build_model, build_scheduler
from gaffer_diffusion.models.model import NeuralGafferModel, vae_posterior
from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training.config import ModelSource, TrainConfig
from gaffer_diffusion.training.dataset import (
    KeySampler,
    RelightTrainDataset,
    TrainBatch,
    batch_lighting_of,
    check_lighting_compat,
    collate_items,
    dataset_object_ids,
    split_object_ids,
)
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.errors import ResumeError, TrainingDivergedError
from gaffer_diffusion.training.tracking import MetricsLogger
from gaffer_diffusion.training.validation import (
    ValidationResult,
    ValidationSet,
    build_validation_set,
    sampling_model,
    validate,
)

logger = logging.getLogger(__name__)

StopReason = Literal["max_steps", "time_limit", "sigterm"]
StepCallback = Callable[[int, float], None]


@dataclass(frozen=True, kw_only=True)
class TrainResult:
    """What a `train` call did.

    Attributes:
        step: optimiser steps completed in total (including those before a resume).
        start_step: the step this call started from (0, or the resumed checkpoint's).
        losses: mean loss of every optimiser step of this call (this process), NaN for skipped steps.
        stop_reason: "max_steps", "time_limit" or "sigterm".
        checkpoint: the last checkpoint written, or None.
        final_model: `output_dir/final` (EMA weights, our model format) when training finished.
        skipped_steps: steps skipped for NaN/Inf (whole run).
        skipped_samples: unreadable samples replaced by the data loader (whole run).
        validations: the validations run by this call.
        seconds: wall time of this call.
    """

    step: int
    start_step: int
    losses: tuple[float, ...]
    stop_reason: StopReason
    checkpoint: Path | None
    final_model: Path | None
    skipped_steps: int
    skipped_samples: int
    validations: tuple[ValidationResult, ...]
    seconds: float


def build_training_model(source: ModelSource) -> NeuralGafferModel:
    """The networks named by `source` (float32, CPU).

    Raises:
        ConfigError: a preset resolution that is not a multiple of 8.
        CheckpointNotFoundError: a local folder or file is missing (from the loaders).
    """
    from gaffer_diffusion.loading import load_pretrained, load_zero123_xl

    match source.init:
        case "preset":
            cfg = get_preset(source.preset)
            if source.resolution is not None:
                if source.resolution % cfg.vae.downsampling_factor:
                    raise ConfigError(
                        f"`model.resolution` is {source.resolution}; it must be a multiple of "
                        f"{cfg.vae.downsampling_factor}."
                    )
                cfg = cfg.with_resolution(source.resolution)
            return build_model(cfg, seed=source.seed)
        case "zero123-xl":
            result = load_zero123_xl(str(source.path))
            logger.info("%s", result.report.summary())
            return result.model
        case "pretrained":
            result = load_pretrained(str(source.path))
            logger.info("%s", result.report.summary())
            return result.model


def _step_generator(seed: int, step: int, rank: int, micro: int) -> torch.Generator:
    state = np.random.SeedSequence([seed, step, rank, micro]).generate_state(2, dtype=np.uint64)
    return torch.Generator().manual_seed(int(state[0]) & 0x7FFF_FFFF_FFFF_FFFF)


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


class _Trainer:
    """State of one `train` call (kept in one object so the loop stays readable)."""

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
    def loss(self, unet: torch.nn.Module, batch: TrainBatch, gen: torch.Generator) -> torch.Tensor:
        """The MSE of one micro-batch against the scheduler's `prediction_type` target (epsilon by
        default; see the module docstring and `_prediction_target`)."""
        cfg, dev, m = self.cfg, self.device, self.model
        b, t = batch.batch_size, batch.targets_per_sample
        n = b * t
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
            sampled = posterior.sample(generator=gen).float()
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
            if alphas is not None:  # radiance hints of the (possibly mirrored) inputs' masks
                mask = alphas.repeat_interleave(t, dim=0)
                parts.append(hints_at(mask, ldr, hdr, int(image_lat.shape[-1])))
        cond = torch.cat(parts, dim=1)  # [BT, 12 (+12 hints), h, w]
        noise = torch.randn(z0.shape, generator=gen).to(dev)
        lo, hi = cfg.train.timestep_range  # checked against the schedule at start-up
        timesteps = torch.randint(lo, hi + 1, (n,), generator=gen).to(dev)
        r = torch.rand(n, generator=gen).to(dev)
        drop_clip, drop_lat = cfg_dropout_masks(r, cfg.train.cfg_dropout_p)
        clip = clip * (~drop_clip).to(clip.dtype).view(n, 1, 1)
        cond = cond * (~drop_lat).to(cond.dtype).view(n, 1, 1, 1)
        abar = self.alphas_cumprod[timesteps].float().view(n, 1, 1, 1)
        z_t = abar.sqrt() * z0 + (1.0 - abar).sqrt() * noise  # forward process q(z_t | z_0)
        with self.acc.autocast():
            # [BT, 16 (+12), h, w]  z_t + 3x4 conditioning latents (+ hints)
            pred = unet(torch.cat([z_t, cond], dim=1), timesteps, encoder_hidden_states=clip).sample
        target = _prediction_target(m.config.scheduler.prediction_type, z0, noise, abar)
        return diffusion_loss(pred.float(), target, z0, cfg.train.residual_loss_floor)


def _mirror_views(
    inputs: Float[Tensor, "B 3 H W"],
    targets: Float[Tensor, "BT 3 H W"],
    ldr: Float[Tensor, "BT 3 H W"],
    hdr: Float[Tensor, "BT 3 H W"],
    targets_per_view: int,
    prob: float,
    gen: torch.Generator,
    alphas: Float[Tensor, "B 1 H W"] | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """Flip each view left-right with probability `prob`: its input (and mask), its targets and,
    mirrored in camera x, their lighting maps (`DataConfig.mirror_prob`)."""
    from gaffer_envmap.augment import mirror_camera_x

    b = inputs.shape[0]
    flip_view = (torch.rand(b, generator=gen) < prob).to(inputs.device)  # [B]
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


class _SigtermFlag:
    def __init__(self, enabled: bool) -> None:
        self.set = False
        self._old: Any = None
        self.enabled = enabled and _in_main_thread()

    def __enter__(self) -> "_SigtermFlag":
        if self.enabled:
            self._old = signal.signal(signal.SIGTERM, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        self.set = True

    def __exit__(self, *exc: object) -> None:
        if self.enabled:
            signal.signal(signal.SIGTERM, self._old)


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _make_accelerator(config: TrainConfig) -> Any:
    try:
        from accelerate import Accelerator
        from accelerate.state import AcceleratorState
    except ImportError as exc:
        raise MissingDependencyError(
            'Training needs accelerate: pip install "gaffer-diffusion[train]"'
        ) from exc
    if int(os.environ.get("WORLD_SIZE", "1")) == 1:
        # a fresh single-process state per call, so one process can run several trainings (tests)
        AcceleratorState._reset_state(reset_partial_state=True)
    mixed_precision = config.train.mixed_precision
    if mixed_precision == "bf16" and not _gpu_available() and not cpu_has_bf16():
        # measured (gaffer-tiny stage 3, 2-core AMD EPYC with AVX2 only): 75 s per step in emulated
        # bf16 vs 2.6 s in fp32 (with AVX512-BF16, bf16 was faster than fp32). On a CPU bf16 is a
        # speed choice only, so fp32 keeps the run's results and makes it feasible (CI's smoke
        # training did 2 steps in 3 minutes on such a machine before this fallback).
        logger.warning(
            "`train.mixed_precision` bf16 on a CPU without native bf16 (no AVX512-BF16/AMX): torch "
            "would emulate it, about 30x slower; training in fp32 instead "
            '(set `train.mixed_precision` to "no" to silence this).'
        )
        mixed_precision = "no"
    acc = Accelerator(
        mixed_precision=mixed_precision,
        gradient_accumulation_steps=config.train.grad_accum,
        project_dir=str(config.output_dir),
    )
    if config.train.mixed_precision == "fp16" and acc.device.type == "cpu":
        logger.warning(
            "`train.mixed_precision` fp16 on a CPU: autocast/grad scaling are GPU features"
        )
    return acc


def _gpu_available() -> bool:
    """Whether accelerate will place the run on a GPU (CUDA or Apple MPS)."""
    mps = getattr(torch.backends, "mps", None)
    return torch.cuda.is_available() or bool(mps is not None and mps.is_available())


def cpu_has_bf16() -> bool:
    """Whether this CPU runs bf16 natively (oneDNN's check: AVX512-BF16 or AMX)."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def _batches(loader: torch.utils.data.DataLoader) -> Iterator[TrainBatch]:
    yield from loader


def train(
    config: TrainConfig,
    *,
    resume: bool | str | Path = False,
    on_step: StepCallback | None = None,
) -> TrainResult:
    """Train (or resume training) the UNet as `config` says.

    Args:
        config: the run.
        resume: False (start fresh; refuses a non-empty checkpoint folder), True (the newest complete
            checkpoint under `output_dir/checkpoints`) or a checkpoint folder.
        on_step: called as `on_step(step, loss)` after every optimiser step (tests, notebooks).

    Returns:
        A `TrainResult`.

    Raises:
        ResumeError: `resume` without a checkpoint, or fresh start over existing checkpoints.
        TrainingDivergedError: too many consecutive NaN/Inf steps (a checkpoint is written first).
        DataError: no usable data.
    """
    t_start = time.perf_counter()
    cfg = config
    acc = _make_accelerator(cfg)
    out = Path(cfg.output_dir)
    ckpt_root = out / "checkpoints"
    if acc.is_main_process:
        ckpt_root.mkdir(parents=True, exist_ok=True)
        removed = ckpt.remove_stale_temporaries(ckpt_root)
        if removed:
            logger.warning("removed %d incomplete checkpoint folder(s) of a killed run", removed)
    acc.wait_for_everyone()

    resume_from: Path | None = None
    if resume is True:
        resume_from = ckpt.latest_checkpoint(ckpt_root)
        if resume_from is None:
            raise ResumeError(
                f"`--resume` was given but {ckpt_root} holds no complete checkpoint; start without "
                "`--resume`."
            )
    elif resume:
        resume_from = Path(resume)
    elif ckpt.list_checkpoints(ckpt_root):
        raise ResumeError(
            f"{ckpt_root} already holds checkpoints; pass `--resume` to continue that run or choose "
            "another `output_dir`."
        )

    if cfg.train.allow_tf32 and torch.cuda.is_available():
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True

    model = build_training_model(cfg.model)
    trainer = _Trainer(cfg, acc, model)
    for frozen in (model.vae, model.image_encoder):
        # VAE and CLIP are frozen (official implementation §3); plain Module.to avoids diffusers' log
        torch.nn.Module.to(frozen.requires_grad_(False).eval(), acc.device, trainer.weight_dtype)
    unet = model.unet
    unet.requires_grad_(True).train()
    if cfg.train.gradient_checkpointing:
        unet.enable_gradient_checkpointing()
    o = cfg.optim
    optimizer = torch.optim.AdamW(
        unet.parameters(), lr=o.lr, betas=o.betas, weight_decay=o.weight_decay, eps=o.eps
    )
    unet, optimizer = acc.prepare(unet, optimizer)
    ema = EMAModel(acc.unwrap_model(unet), cfg.train.ema_decay) if cfg.train.ema_decay > 0 else None

    # ---------------------------------------------------------------- data
    res = model.config.resolution
    # renders and converted authors' splits (`gaffer-data convert-authors`) alike, in any mix
    train_roots = [cfg.data.root, *cfg.data.extra_roots]
    check_lighting_compat(
        [*train_roots, *([] if cfg.data.val_root is None else [cfg.data.val_root])],
        cfg.data.lighting_compat,
    )
    if cfg.data.val_root is not None:
        val_ids, val_roots = None, [cfg.data.val_root]
        held_out: tuple[str, ...] = ()
    else:
        all_ids = dataset_object_ids(cfg.data.root)
        _, val_list = split_object_ids(all_ids, cfg.data.val_objects)
        val_ids, val_roots, held_out = val_list, [cfg.data.root], val_list
    # held-out ids are left out of every training root (a copy of one elsewhere cannot leak in)
    train_ds = RelightTrainDataset(
        train_roots, cfg.data, res, seed=cfg.train.seed, exclude=held_out
    )
    valset: ValidationSet | None = None
    if cfg.validation.every_steps > 0 and (val_ids is None or val_ids):
        val_ds = RelightTrainDataset(
            val_roots,
            dataclasses.replace(cfg.data, targets_per_sample=1),
            res,
            seed=cfg.validation.seed,
            include=val_ids,
        )
        valset = build_validation_set(val_ds, cfg.validation.num_samples)
    logger.info(
        "training on %d views of %d objects; %s held-out validation pairs",
        len(train_ds),
        len(train_ds.objects),
        0 if valset is None else valset.size,
    )

    # ---------------------------------------------------------------- resume
    state = ckpt.TrainState(
        step=0, samples_seen=0, world_size=acc.num_processes, config=cfg.to_dict()
    )
    if resume_from is not None:
        state = ckpt.read_state(resume_from)
        acc.load_state(str(resume_from))
        if ema is not None:
            ema_file = resume_from / ckpt.EMA_NAME
            if ema_file.is_file():
                ema.load(str(ema_file))
            else:
                logger.warning(
                    "%s has no EMA weights; the EMA restarts from the current weights", resume_from
                )
                ema = EMAModel(acc.unwrap_model(unet), cfg.train.ema_decay)
        if state.world_size != acc.num_processes:
            logger.warning(
                "resuming a %d-process run on %d processes: the data order differs from the original",
                state.world_size,
                acc.num_processes,
            )
        logger.info("resumed from %s at step %d", resume_from, state.step)
    start_step = state.step

    b = cfg.train.batch_size
    per_step_samples = b * cfg.train.grad_accum * acc.num_processes
    sampler = KeySampler(
        len(train_ds),
        seed=cfg.train.seed,
        start=state.samples_seen,
        rank=acc.process_index,
        world_size=acc.num_processes,
    )
    nw = cfg.data.num_workers
    loader = torch.utils.data.DataLoader(
        train_ds,
        batch_size=b,
        sampler=sampler,
        collate_fn=collate_items,
        num_workers=nw,
        pin_memory=acc.device.type == "cuda",
        persistent_workers=nw > 0,
        prefetch_factor=4 if nw > 0 else None,
    )
    batches = _batches(loader)

    log = MetricsLogger(
        out / "logs", enabled=acc.is_main_process, tensorboard=cfg.logging.tensorboard
    )
    progress = None
    if cfg.logging.progress_bar and acc.is_main_process:
        from tqdm.auto import tqdm

        progress = tqdm(total=cfg.train.max_steps, initial=state.step, desc="train", unit="step")

    losses: list[float] = []
    validations: list[ValidationResult] = []
    last_ckpt: Path | None = resume_from
    window = {"loss": 0.0, "n": 0, "wait": 0.0, "time": 0.0, "samples": 0}
    stop: StopReason = "max_steps"
    unet_module = acc.unwrap_model(unet)

    def save(step_state: ckpt.TrainState) -> Path:
        tmp = ckpt.temporary_dir(ckpt_root, step_state.step)
        if acc.is_main_process:
            tmp.mkdir(parents=True, exist_ok=True)
        acc.wait_for_everyone()
        acc.save_state(str(tmp))
        if acc.is_main_process:
            if ema is not None:
                ema.save(str(tmp / ckpt.EMA_NAME))
            ckpt.write_state(tmp, step_state)
            ckpt.publish(tmp, ckpt_root, step_state.step, cfg.checkpoint.keep)
        acc.wait_for_everyone()
        final = ckpt_root / ckpt.checkpoint_name(step_state.step)
        logger.info("saved checkpoint %s", final)
        return final

    def run_validation(step: int) -> None:
        if valset is None or not acc.is_main_process:
            return
        smodel = sampling_model(model, unet_module, ema if cfg.validation.use_ema else None)
        dtype = {torch.float16: "float16", torch.bfloat16: "bfloat16"}.get(
            trainer.weight_dtype, "float32"
        )
        result = validate(
            smodel,
            valset,
            cfg.validation,
            step=step,
            compat=cfg.data.lighting_compat,
            device=acc.device,
            dtype=dtype,
            sheet_dir=(out / "val") if cfg.validation.save_images else None,
        )
        validations.append(result)
        log.log(
            step, {"psnr": result.psnr, "psnr_identity": result.psnr_identity}, kind="validation"
        )
        if result.sheet is not None and log.tensorboard_enabled:
            from PIL import Image

            log.log_image(step, "validation/input_pred_gt", np.asarray(Image.open(result.sheet)))
        logger.info(
            "step %d validation: PSNR %.2f dB (identity baseline %.2f dB)",
            step,
            result.psnr,
            result.psnr_identity,
        )

    with _SigtermFlag(cfg.checkpoint.on_sigterm) as sigterm:
        try:
            while state.step < cfg.train.max_steps:
                step = state.step
                t0 = time.perf_counter()
                wait = 0.0
                micro_losses: list[float] = []
                skipped_samples = 0
                for micro in range(cfg.train.grad_accum):
                    tw = time.perf_counter()
                    batch = next(batches)
                    wait += time.perf_counter() - tw
                    skipped_samples += batch.skipped
                    gen = _step_generator(cfg.train.seed, step, acc.process_index, micro)
                    with acc.accumulate(unet):
                        loss = trainer.loss(unet, batch, gen)
                        acc.backward(loss)
                    micro_losses.append(float(loss.detach()))
                lr = o.lr_at(step)
                for group in optimizer.param_groups:
                    group["lr"] = lr
                step_loss = float(np.mean(micro_losses))
                # every process must take the same decision (DDP): reduce the "bad" flag
                bad = torch.tensor([0.0 if math.isfinite(step_loss) else 1.0], device=acc.device)
                bad = acc.reduce(bad, reduction="sum")
                grad_norm = float("nan")
                applied = False
                if float(bad.item()) == 0.0:
                    max_norm = o.max_grad_norm if o.max_grad_norm is not None else float("inf")
                    grad_norm = float(acc.clip_grad_norm_(unet.parameters(), max_norm))
                    if math.isfinite(grad_norm) or acc.scaler is not None:
                        optimizer.step()  # the fp16 scaler skips (and lowers its scale) on Inf grads
                        applied = not acc.optimizer_step_was_skipped and math.isfinite(grad_norm)
                optimizer.zero_grad(set_to_none=True)
                if applied:
                    if ema is not None:
                        ema.update(unet_module)
                    consecutive = 0
                    skipped_total = state.skipped_steps
                else:
                    consecutive = state.consecutive_nonfinite + 1
                    skipped_total = state.skipped_steps + 1
                    logger.warning(
                        "step %d: non-finite loss (%s) or gradient norm (%s); step skipped",
                        step,
                        step_loss,
                        grad_norm,
                    )
                state = dataclasses.replace(
                    state,
                    step=step + 1,
                    samples_seen=state.samples_seen + per_step_samples,
                    skipped_steps=skipped_total,
                    consecutive_nonfinite=consecutive,
                    skipped_samples=state.skipped_samples + skipped_samples,
                )
                losses.append(step_loss if applied else float("nan"))
                dt = time.perf_counter() - t0
                window["loss"] += step_loss if applied else 0.0
                window["n"] += 1 if applied else 0
                window["wait"] += wait
                window["time"] += dt
                window["samples"] += per_step_samples
                if progress is not None:
                    progress.update(1)
                    progress.set_postfix(loss=f"{step_loss:.4f}", lr=f"{lr:.2e}")
                if on_step is not None:
                    on_step(state.step, step_loss)

                if consecutive >= cfg.train.max_consecutive_nonfinite:
                    # the weights were never touched by the bad steps: this checkpoint is usable
                    last_ckpt = save(state)
                    raise TrainingDivergedError(
                        state.step, consecutive, last_ckpt, cfg.train.mixed_precision
                    )
                if state.step % cfg.logging.every_steps == 0 or state.step == cfg.train.max_steps:
                    log.log(
                        state.step,
                        {
                            "loss": window["loss"] / max(window["n"], 1),
                            "lr": lr,
                            "samples_per_s": window["samples"] / max(window["time"], 1e-9),
                            "data_wait_share": window["wait"] / max(window["time"], 1e-9),
                            "grad_norm": grad_norm,
                            "skipped_steps": state.skipped_steps,
                            "skipped_samples": state.skipped_samples,
                        },
                    )
                    if state.skipped_samples:
                        logger.info("%d unreadable samples skipped so far", state.skipped_samples)
                    window = {"loss": 0.0, "n": 0, "wait": 0.0, "time": 0.0, "samples": 0}
                ve = cfg.validation.every_steps
                if ve > 0 and state.step % ve == 0 and state.step < cfg.train.max_steps:
                    run_validation(state.step)
                if (
                    state.step % cfg.checkpoint.every_steps == 0
                    and state.step < cfg.train.max_steps
                ):
                    last_ckpt = save(state)
                flag = torch.tensor([1.0 if sigterm.set else 0.0], device=acc.device)
                if float(acc.reduce(flag, reduction="sum").item()) > 0:
                    stop = "sigterm"
                    break
                limit = cfg.train.max_time_s
                if limit is not None and time.perf_counter() - t_start > limit:
                    stop = "time_limit"
                    break
        finally:
            if progress is not None:
                progress.close()

    if last_ckpt is None or ckpt.read_state(last_ckpt).step != state.step:
        last_ckpt = save(state)
    final_model: Path | None = None
    if stop != "sigterm":
        if cfg.validation.every_steps > 0:
            run_validation(state.step)
        if acc.is_main_process:
            from gaffer_diffusion.loading import save_pretrained
            from gaffer_diffusion.suggested import suggestion_from_training_config

            final_model = save_pretrained(
                sampling_model(model, unet_module, ema),
                out / "final",
                suggested=suggestion_from_training_config(cfg.to_dict()),
            )
        acc.wait_for_everyone()
    log.close()
    if state.skipped_samples:
        logger.warning("%d unreadable samples were skipped in this run", state.skipped_samples)
    with contextlib.suppress(Exception):
        acc.end_training()
    return TrainResult(
        step=state.step,
        start_step=start_step,
        losses=tuple(losses),
        stop_reason=stop,
        checkpoint=last_ckpt,
        final_model=final_model,
        skipped_steps=state.skipped_steps,
        skipped_samples=state.skipped_samples,
        validations=tuple(validations),
        seconds=time.perf_counter() - t_start,
    )


def load_checkpoint_model(checkpoint: str | Path, *, use_ema: bool = True) -> NeuralGafferModel:
    """Rebuild the model of a training checkpoint (its config's networks + the saved UNet / EMA).

    Args:
        checkpoint: a `checkpoint-*` folder.
        use_ema: load the EMA weights (else the raw trained weights).

    Raises:
        ResumeError: not a complete checkpoint.
    """
    from gaffer_diffusion.loading import load_checked, read_state_dict

    folder = Path(checkpoint)
    state = ckpt.read_state(folder)
    cfg = TrainConfig.from_dict(state.config)
    model = build_training_model(cfg.model)
    weights = folder / "model.safetensors"
    if not weights.is_file():
        weights = folder / "pytorch_model.bin"
    load_checked(model.unet, read_state_dict(weights), source=str(weights))
    if use_ema and (folder / ckpt.EMA_NAME).is_file():
        ema = EMAModel(model.unet, cfg.train.ema_decay or 0.9999)
        ema.load(str(folder / ckpt.EMA_NAME))
        ema.copy_to(model.unet)
    return model.eval()
