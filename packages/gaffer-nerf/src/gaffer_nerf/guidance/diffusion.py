"""The relighting diffusion model as a prior for 3D: relit views (Stage 1), guidance targets (Stage 2), SDS.

Built on gaffer-diffusion's public API only: the pipeline samples (`RelightPipeline.sample` for
Stage 1's relit views, `RelightPipeline.denoise_from` for Stage 2's targets from an intermediate
noise level t*, SDEdit, paper §3.3 Eq. 3) and predicts noise (`RelightPipeline.predict_noise`, SDS),
with the same loop, classifier-free guidance and decoding as `gaffer-diffusion relight`.
`DiffusionGuide` adds what is 3D's own: the views' framing (`guidance.framing`), per-view seeds, the
mirror mean over encoded views, the t* schedule and the SDS gradient. Every path takes its steps,
guidance, averaging, encoding and latent mode from one resolved `DiffusionSamplingConfig`: the user's
values over the model's own (`RelightPipeline.default_sampling`).
"""

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion import (
    DefaultSampling,
    EncodedConditions,
    LatentMode,
    LightingMaps,
    RelightingConditions,
    RelightPipeline,
    SamplingConfig,
    lighting_from_envmap,
)
from gaffer_envmap import EnvironmentMap
from gaffer_nerf.configs import CompatName, DiffusionSamplingConfig, Stage2Config
from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.guidance.framing import ViewFraming, frame_views

logger = logging.getLogger(__name__)

ProgressCallback = Callable[[int, int], None]

TargetLighting = EnvironmentMap | np.ndarray | Tensor
"""A target lighting: a `gaffer_envmap.EnvironmentMap` or `[He, We, 3]` linear radiance (Blender world)."""

_T = TypeVar("_T")


def _resolved(value: _T | None, name: str) -> _T:
    """A field of `DiffusionGuide.sampling`, which `DiffusionSamplingConfig.resolved` filled."""
    if value is None:
        raise ConfigError(
            f"`{name}` is unset in the guide's sampling; it must be resolved against the model's "
            "suggestion (`DiffusionSamplingConfig.resolved`) first."
        )
    return value


@dataclass(frozen=True, kw_only=True)
class ViewConditions:
    """Per-view conditioning of the relighting model, encoded once.

    Attributes:
        lighting: `[V, 3, R, R]` camera-frame LDR/HDR maps of the target lighting.
        encoded: the VAE latents of each input view and its maps, and the CLIP embeddings.
        mirrored: the same of every view flipped left-right under the lighting mirrored in camera x
            (`DiffusionSamplingConfig.mirror_average`), else None.
        framing: the views' object-centred crop boxes (`DiffusionSamplingConfig.object_fraction`),
            None: whole views resized to the model's resolution.
    """

    lighting: LightingMaps
    encoded: EncodedConditions
    mirrored: EncodedConditions | None = None
    framing: ViewFraming | None = None

    @property
    def num_views(self) -> int:
        """V."""
        return self.encoded.batch_size


def t_star(step: int, total: int, config: Stage2Config) -> float:
    """Stage-2 noise level t* (fraction of the 1000 training timesteps) at `step` of `total`.

    "exponential" (paper §4.1): t* = t_start (t_end / t_start)^(k / (K - 1)), 0.4 -> 0.05.
    "authors": t* = t_end + (t_start - t_end)(1 - exp(-(K - k))), which reproduces what their code does
    (reference §6: "about 0.38-0.4 for ~497 of 500"): here 498 of 500 steps are within 0.38-0.40. It is a reconstruction of
    the schedule's shape, not their formula.

    Example:
        >>> from gaffer_nerf.configs import Stage2Config
        >>> c = Stage2Config()
        >>> round(t_star(0, 500, c), 3), round(t_star(499, 500, c), 3)
        (0.4, 0.05)
        >>> a = Stage2Config(t_schedule="authors")
        >>> sum(t_star(k, 500, a) >= 0.38 for k in range(500))
        498
    """
    k, n = step, max(total, 1)
    match config.t_schedule:
        case "exponential":
            if n == 1:
                return config.t_start
            return config.t_start * (config.t_end / config.t_start) ** (k / (n - 1))
        case "authors":
            return config.t_end + (config.t_start - config.t_end) * (1.0 - math.exp(-(n - k)))


class DiffusionGuide:
    """The diffusion model, wrapped for the 3D relighting stages.

    Args:
        pipeline: a `RelightPipeline` (real weights, or the random `guidance.model.smoke_model()`).
        sampling: steps, guidance scale, averaging, encoding, batch size and seeds; None fields
            take the model's suggestion.
        suggested: the model's own sampling; None: `pipeline.default_sampling` (read once from its
            folder by `gaffer_diffusion.load_pipeline`).

    Attributes:
        requested: `sampling` as given.
        suggested: the model's suggestion.
        sampling: the resolved setting every path uses (no None left).
        sds_non_finite: SDS gradient values that were NaN or infinite and were zeroed, since this
            guide was built (Stage 2 reports its own share in `StageReport.sds_non_finite`).
    """

    def __init__(
        self,
        pipeline: RelightPipeline,
        sampling: DiffusionSamplingConfig | None = None,
        suggested: DefaultSampling | None = None,
    ) -> None:
        self.pipeline = pipeline
        self.model = pipeline.model
        self.requested = sampling or DiffusionSamplingConfig()
        self.suggested = suggested or pipeline.default_sampling
        self.sampling = self.requested.resolved(self.suggested)
        for module in (self.model.unet, self.model.vae, self.model.image_encoder):
            module.requires_grad_(False)
        self.sds_non_finite = 0
        self._warned_non_finite = False

    @property
    def resolution(self) -> int:
        """Image side the model works at (256 for the released checkpoint)."""
        return int(self.model.config.resolution)

    def to_model_resolution(self, images: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 3 R R"]:
        """Resize (bilinear, antialiased, differentiable) to the model's square resolution."""
        r = self.resolution
        if tuple(images.shape[2:]) == (r, r):
            return images
        return F.interpolate(
            images, size=(r, r), mode="bilinear", antialias=True, align_corners=False
        )

    def framing(self, alpha: Float[Tensor, "V H W"] | None) -> ViewFraming | None:
        """The views' crop boxes at the resolved `object_fraction` from their coverage `alpha`,
        None when the model sees whole views (or no alpha is known)."""
        fraction = self.sampling.crop_fraction
        if fraction is None or alpha is None:
            return None
        return frame_views(alpha, fraction)

    def model_views(
        self,
        images: Float[Tensor, "B 3 H W"],
        views: list[int],
        framing: ViewFraming | None,
    ) -> Float[Tensor, "B 3 R R"]:
        """Views `views` as the model sees them: their object-centred crops under `framing`, else
        the whole views resized (`to_model_resolution`). Differentiable."""
        if framing is None:
            return self.to_model_resolution(images)
        return framing.crop(images, views, self.resolution)

    def lighting(self, envmap: TargetLighting, w2c_blender: Float[Tensor, "V 3 4"]) -> LightingMaps:
        """Camera-frame LDR/HDR maps of `envmap` for every view (gaffer-envmap's `encode_lighting`)."""
        compat: CompatName = _resolved(self.sampling.compat, "compat")
        return lighting_from_envmap(envmap, w2c_blender, size=self.resolution, compat=compat)

    def sampling_config(self) -> SamplingConfig:
        """The resolved setting as gaffer-diffusion's `SamplingConfig` (what Stage 1 samples with).

        `mirror_average` is done here (on encoded conditions); `RelightPipeline.sample` ignores it.
        The schedule's spacing (where sampling starts) is the model's own (`ModelConfig.scheduler`);
        the sampler is `sampling.scheduler` (DDIM unless asked), for Stage 1 and Stage 2's targets.
        """
        s = self.sampling
        return SamplingConfig(
            num_inference_steps=int(_resolved(s.num_inference_steps, "num_inference_steps")),
            scheduler=s.scheduler or "ddim",
            guidance_scale=float(_resolved(s.guidance_scale, "guidance_scale")),
            average_samples=int(_resolved(s.average_samples, "average_samples")),
            mirror_average=bool(s.mirror_average),
            latent_mode=s.latent_mode or "mode",
        )

    @torch.no_grad()
    def encode_views(
        self,
        images: Float[Tensor, "V 3 H W"],
        lighting: LightingMaps,
        framing: ViewFraming | None = None,
    ) -> ViewConditions:
        """Encode the input views with the target lighting once (batched by `sampling.batch_size`).

        With `framing` (`DiffusionGuide.framing`) each view is cropped to its box first, and the
        conditions keep the boxes for Stage 1 and 2. With `mirror_average` the mirrored views are
        encoded too. With `latent_mode="sample"` view i draws its posterior noise from
        `view_seed(i)` (the mirror from the same seed).
        """
        from gaffer_envmap.augment import mirror_camera_x

        if framing is not None and framing.num_views != images.shape[0]:
            raise ShapeError(
                "framing", (framing.num_views,), f"[{images.shape[0]}] (one box per view)"
            )
        x = self.model_views(images, list(range(images.shape[0])), framing).clamp(0, 1)
        mode = self.sampling.latent_mode or "mode"

        def encode_all(x: Tensor, ldr: Tensor, hdr: Tensor) -> EncodedConditions:
            parts = []
            b = self.sampling.batch_size
            for s in range(0, x.shape[0], b):
                cond = RelightingConditions(
                    image=x[s : s + b],
                    lighting=LightingMaps(ldr=ldr[s : s + b], hdr=hdr[s : s + b]),
                )
                gens = None
                if mode == "sample":
                    seeds = range(s, min(s + b, x.shape[0]))
                    gens = [torch.Generator().manual_seed(self.view_seed(i)) for i in seeds]
                parts.append(self.pipeline.encode(cond, latent_mode=mode, generator=gens))
            return EncodedConditions.cat(parts)

        enc = encode_all(x, lighting.ldr, lighting.hdr)
        mirrored = None
        if self.sampling.mirror_average:
            ldr, hdr = mirror_camera_x(lighting.ldr), mirror_camera_x(lighting.hdr)
            mirrored = encode_all(x.flip(-1), ldr, hdr)
        return ViewConditions(lighting=lighting, encoded=enc, mirrored=mirrored, framing=framing)

    def view_seed(self, index: int) -> int:
        """The noise seed of view `index`: `sampling.seed` for all with `shared_noise`, else + index."""
        return self.sampling.seed + (0 if self.sampling.shared_noise else index)

    def _mirrored(self, mirrored: EncodedConditions | None, where: str) -> EncodedConditions | None:
        if not self.sampling.mirror_average:
            return None
        if mirrored is None:
            raise ConfigError(
                f"{where}: `mirror_average` is on but no mirrored conditions were given; encode the "
                "views with `DiffusionGuide.encode_views` (it encodes the mirrors) and pass "
                "`ViewConditions.mirrored`, or set `DiffusionSamplingConfig(mirror_average=False)`."
            )
        return mirrored

    @torch.no_grad()
    def relight_views(
        self, conditions: ViewConditions, *, callback: ProgressCallback | None = None
    ) -> Float[Tensor, "V 3 R R"]:
        """Stage 1's targets: every view relit from pure noise with the resolved sampling, as the
        model sees it (its crop under `conditions.framing`; `ViewFraming.paste` puts it back).

        View i uses seed `view_seed(i)` (its mirror the same): `sampling.seed + i`, or one seed for
        every view with `shared_noise` (more consistent targets, see `DiffusionSamplingConfig`);
        either way the results do not depend on the batch size. With `mirror_average` the mirrored view's
        result is flipped back and averaged.
        """
        cfg = self.sampling_config()
        mirrored = self._mirrored(conditions.mirrored, "relight_views")
        out = []
        b, v = self.sampling.batch_size, conditions.num_views
        for s in range(0, v, b):
            idx = list(range(s, min(s + b, v)))
            seeds = [self.view_seed(i) for i in idx]
            enc = conditions.encoded.select(idx)
            if mirrored is not None:  # one batch of 2B, as RelightPipeline's mirror mean
                enc = EncodedConditions.cat([enc, mirrored.select(idx)])
                seeds = [*seeds, *seeds]
            images = self.pipeline.sample(enc, cfg, seeds=seeds).images.float().cpu()
            if mirrored is not None:
                n = len(idx)
                images = (images[:n] + images[n:].flip(-1)) / 2.0
            out.append(images)
            if callback is not None:
                callback(idx[-1] + 1, v)
        return torch.cat(out)

    @torch.no_grad()
    def denoise_from(
        self,
        images: Float[Tensor, "B 3 R R"],
        encoded: EncodedConditions,
        t_frac: float,
        *,
        generator: torch.Generator | None = None,
        encode_mode: LatentMode = "mode",
        noise: Tensor | None = None,
        mirrored: EncodedConditions | None = None,
    ) -> Float[Tensor, "B 3 R R"]:
        """Stage 2's target x_relit(t*) (Eq. 3): `RelightPipeline.denoise_from` with the resolved
        sampling (K noises averaged with `average_samples`; with `mirror_average` also the mirrored
        render under `mirrored`, same noise, flipped back and averaged).

        Args:
            images: rendered views in [0, 1] at the model resolution.
            encoded: their views' conditioning (input photo, target lighting).
            t_frac: t* as a fraction of the training timesteps.
            generator: RNG for the posterior sample and the noise (CPU generator).
            encode_mode: VAE posterior "mode" or "sample" for the renders.
            noise: explicit `[B * K, 4, h, w]` noise (item-major) instead of drawing it.
            mirrored: the views' mirrored conditioning (`ViewConditions.mirrored`); needed with
                `mirror_average`.

        Returns:
            The denoised images in [0, 1], float32.
        """
        if images.ndim != 4 or images.shape[1] != 3:
            raise ShapeError("images", tuple(images.shape), "[B, 3, R, R]")
        return self.pipeline.denoise_from(
            images,
            t_frac,
            encoded,
            self.sampling_config(),
            generator=generator,
            latent_mode=encode_mode,
            noise=noise,
            mirrored=self._mirrored(mirrored, "denoise_from"),
        )

    def sds_loss(
        self,
        images: Float[Tensor, "B 3 R R"],
        encoded: EncodedConditions,
        config: Stage2Config,
        *,
        generator: torch.Generator | None = None,
        mirrored: EncodedConditions | None = None,
    ) -> Tensor:
        """Score distillation (DreamFusion): gradient w(t)(eps_hat - eps) on the latent, as a loss.

        loss = 0.5 || z_0 - sg(z_0 - g) ||^2 / B with g = weight (1 - alpha_bar_t)(eps_hat(z_t) - eps),
        so d loss / d z_0 = g; it reaches the rendered image through the VAE encoder. The CFG scale
        is `config.sds_guidance_scale`, else the model's (`sampling.guidance_scale`). With
        `mirror_average` it is the mean of the loss of the view and of its mirror under `mirrored`.
        """
        mirror = self._mirrored(mirrored, "sds_loss")
        if mirror is not None:
            a = self._sds_one(images, encoded, config, generator)
            return 0.5 * (a + self._sds_one(images.flip(-1), mirror, config, generator))
        return self._sds_one(images, encoded, config, generator)

    def sds_guidance(self, config: Stage2Config) -> float:
        """The CFG scale SDS uses: `config.sds_guidance_scale`, else the model's."""
        g = config.sds_guidance_scale
        if g is None:
            return float(_resolved(self.sampling.guidance_scale, "guidance_scale"))
        return float(g)

    def _sds_one(
        self,
        images: Tensor,
        encoded: EncodedConditions,
        config: Stage2Config,
        generator: torch.Generator | None,
    ) -> Tensor:
        pipe = self.pipeline
        enc = encoded.to(device=pipe.device, dtype=pipe.dtype)
        n_train = pipe.num_train_timesteps
        lo, hi = config.sds_t_range
        t = torch.randint(int(lo * n_train), int(hi * n_train) + 1, (1,), generator=generator)
        t = t.to(pipe.device)
        z0 = pipe.encode_images(images, enc, latent_mode=config.encode_mode, generator=generator)
        noise = torch.randn(z0.shape, generator=generator, dtype=torch.float32).to(z0)
        with torch.no_grad():
            z_t = pipe.add_noise(z0.detach(), noise, t.repeat(z0.shape[0]))
            guidance = self.sds_guidance(config)
            eps = pipe.predict_noise(z_t, t, enc, guidance_scale=guidance, as_epsilon=True)
            alpha_bar = pipe.alpha_bar(t).to(z0.dtype)
            grad = config.sds_weight * (1.0 - alpha_bar) * (eps - noise)
            grad = self._zero_non_finite(grad, int(t))
        target = (z0 - grad).detach()
        return 0.5 * F.mse_loss(z0.float(), target.float(), reduction="sum") / z0.shape[0]

    def _zero_non_finite(self, grad: Tensor, t: int) -> Tensor:
        """`grad` with NaN/Inf values zeroed, counted in `sds_non_finite` (warned about once)."""
        finite = torch.isfinite(grad)
        bad = int((~finite).sum())
        if bad == 0:
            return grad
        self.sds_non_finite += bad
        if not self._warned_non_finite:
            self._warned_non_finite = True
            logger.warning(
                "SDS gradient: %d of %d values are NaN or infinite at timestep %d; zeroed. Further "
                "ones are zeroed without a warning and counted in `StageReport.sds_non_finite`.",
                bad,
                grad.numel(),
                t,
            )
        return torch.where(finite, grad, torch.zeros_like(grad))
