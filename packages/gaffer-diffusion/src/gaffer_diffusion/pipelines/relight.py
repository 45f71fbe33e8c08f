"""`RelightPipeline`: relight object images under new lighting (paper §3.2, official implementation §2).

Sampling: z_T ~ N(0, I); for each timestep t the UNet sees `[z_t, E(x), E(E_H), E(E_L)]` (16 channels)
and the CLIP context c(x). Classifier-free guidance uses an unconditional branch with the CLIP embedding
AND all three conditioning latents zeroed: eps = eps_u + s (eps_c - eps_u). The final latent is divided
by the VAE scaling factor, decoded, and mapped from [-1, 1] to [0, 1].

Conditioning is encoded once (`encode`) and reused for every seed and step (`sample`).
Non-finite output (NaN/Inf, typically fp16 overflow) is never returned silently: it raises
`NonFiniteOutputError` or, with `SamplingConfig(nonfinite="retry_fp32")`, the affected items are rerun
from the same initial noise with float32 copies of the networks.
"""

import copy
import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, cast

import torch
from diffusers.schedulers.scheduling_ddim import DDIMScheduler
from diffusers.utils.torch_utils import randn_tensor
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion import pretrained
from gaffer_diffusion.conditioning import (
    EncodedConditions,
    LatentMode,
    LightingMaps,
    RelightingConditions,
    encode_conditions,
)
from gaffer_diffusion.errors import ConfigError, NonFiniteOutputError
from gaffer_diffusion.models.model import NeuralGafferModel, vae_decode, vae_posterior
from gaffer_diffusion.photo_encoding import PhotoEncodingCache
from gaffer_diffusion.pipelines.config import RuntimeConfig, SamplingConfig
from gaffer_diffusion.runtime_dtype import prepare_for_inference, resolve_runtime
from gaffer_diffusion.schedulers import Sampler, make_scheduler
from gaffer_diffusion.suggested import PAPER_SAMPLING, DefaultSampling

logger = logging.getLogger(__name__)

GeneratorArg = torch.Generator | Sequence[torch.Generator] | None
StepCallback = Callable[[int, int], None]


@dataclass(frozen=True, kw_only=True)
class RelightOutput:
    """Result of a sampling call.

    Attributes:
        images: `[N, 3, H, W]` float32 relit images in [0, 1] (N = B x images per condition,
            ordered item0-seed0, item0-seed1, ..., item1-seed0, ...).
        latents: `[N, 4, h, w]` final (scaled) latents, in the pipeline dtype.
        retried_in_fp32: indices of items that produced NaN/Inf and were rerun in float32.
    """

    images: Float[Tensor, "N 3 H W"]
    latents: Float[Tensor, "N 4 h w"]
    retried_in_fp32: tuple[int, ...] = ()


GAFFER_TINY_NAME = "gaffer-tiny"
"""`ModelConfig.name` of gaffer-tiny (`get_preset("gaffer-tiny")`, the shipped weights)."""


def default_sampling_for(model: NeuralGafferModel) -> DefaultSampling:
    """The sampling of a model built in memory (not loaded from a folder by `load_pipeline`).

    A model of gaffer-tiny's config (the shipped weights loaded by hand, or a retrain) gets what the
    shipped gaffer-tiny folder records (read from its manifest); any other the paper's.
    """
    if model.config.name == GAFFER_TINY_NAME:
        return pretrained.gaffer_tiny_sampling()
    return PAPER_SAMPLING


def _nonfinite_items(x: Tensor) -> list[int]:
    return torch.nonzero(~torch.isfinite(x.flatten(1)).all(dim=1)).flatten().tolist()


class RelightPipeline:
    """Diffusion sampling for a `NeuralGafferModel`.

    Args:
        model: the networks (moved in place to `runtime.device` / `runtime.dtype`).
        runtime: device, dtype, attention kernels and `torch.compile`.
        default_sampling: how the model is meant to be sampled (`load_pipeline` reads it from the
            model folder); None: `default_sampling_for(model)`.
        source: the folder the weights came from, for reports (None: built in memory).

    Attributes:
        default_sampling: the model's own sampling, frozen; callers override it
            (`DefaultSampling.override`, `DefaultSampling.sampling_config`), never re-read it.

    Example:
        >>> import torch
        >>> from gaffer_diffusion import build_model, get_preset, LightingMaps, RelightingConditions, SamplingConfig
        >>> pipe = RelightPipeline(build_model(get_preset("tiny")))
        >>> x = torch.rand(1, 3, 64, 64)
        >>> cond = RelightingConditions(image=x, lighting=LightingMaps(ldr=x, hdr=x))
        >>> out = pipe(cond, SamplingConfig(num_inference_steps=2), seeds=[0])
        >>> out.images.shape
        torch.Size([1, 3, 64, 64])
    """

    def __init__(
        self,
        model: NeuralGafferModel,
        runtime: RuntimeConfig | None = None,
        *,
        default_sampling: DefaultSampling | None = None,
        source: Path | None = None,
    ) -> None:
        # `dtype="auto"` resolved for this model; `dtype_choice` says what and why
        self.runtime, self.dtype_choice = resolve_runtime(model, runtime or RuntimeConfig())
        # read once (`load_pipeline` reads the model folder); callers only override it
        self.default_sampling: DefaultSampling = default_sampling or default_sampling_for(model)
        self.source = source
        self.model = model.to(device=self.runtime.device, dtype=self.runtime.weights_dtype).eval()
        prepare_for_inference(self.model, self.runtime)  # SDPA; channels-last on the bf16 CPU path
        self._unet: Callable[..., object] = self.model.unet
        if self.runtime.compile:
            # on a CPU, inductor's inference mode ("freezing": weights folded in and packed for
            # oneDNN) is what makes compiling pay: `benchmarks/results/cpu_fast_compile.json`
            freeze = (
                self.device.type == "cpu"
                and self.runtime.compile_backend == "inductor"
                and self.runtime.compile_mode is None
            )
            self._unet = torch.compile(
                self.model.unet,
                mode=self.runtime.compile_mode,
                backend=self.runtime.compile_backend,
                options={"freezing": True} if freeze else None,
            )
        if self.runtime.autocast:
            self._unet = _under_autocast(self._unet, self.device.type, self.runtime.torch_dtype)
        self._fp32: NeuralGafferModel | None = None
        self._photo_cache = PhotoEncodingCache()
        self._noise_schedule: Sampler | None = None

    @property
    def device(self) -> torch.device:
        """The device the networks run on."""
        return torch.device(self.runtime.device)

    @property
    def dtype(self) -> torch.dtype:
        """The dtype the networks are kept in (float32 under `RuntimeConfig.autocast`)."""
        return self.runtime.weights_dtype

    def encode(
        self,
        conditions: RelightingConditions,
        *,
        latent_mode: LatentMode = "mode",
        generator: torch.Generator | Sequence[torch.Generator] | None = None,
    ) -> EncodedConditions:
        """Encode image and lighting once (one batched VAE call + CLIP); reuse for many seeds.

        Args:
            conditions: `[B, 3, H, W]` image and lighting maps in [0, 1].
            latent_mode: posterior "mode" (default) or "sample" (the authors' inference).
            generator: RNG for `latent_mode="sample"`: one, or one per item (each draws its item's
                image, HDR and LDR posterior noise in that order).

        Returns:
            `EncodedConditions` on the pipeline's device and dtype.
        """
        return encode_conditions(
            self.model,
            conditions,
            latent_mode=latent_mode,
            generator=generator,
            photo_cache=self._photo_cache,  # one photo, many lightings: one VAE/CLIP encode
        )

    def initial_noise(
        self, batch_size: int, *, generator: GeneratorArg = None, seeds: Sequence[int] | None = None
    ) -> Float[Tensor, "N 4 h w"]:
        """Standard-normal initial latents z_T, drawn per item so results do not depend on batching.

        Args:
            batch_size: N.
            generator: one generator, or one per item.
            seeds: one seed per item (CPU generators, so a seed gives the same noise on every device).

        Returns:
            `[N, 4, h, w]` noise on the pipeline device, in the pipeline dtype.
        """
        gens = self._generators(batch_size, generator, seeds)
        h = self.model.config.latent_size
        shape = (batch_size, self.model.config.vae.latent_channels, h, h)
        if isinstance(gens, list):
            noise = torch.cat(
                [torch.randn((1, *shape[1:]), generator=g, device=g.device) for g in gens]
            )
        else:
            noise = randn_tensor(
                shape, generator=gens, device=torch.device("cpu"), dtype=torch.float32
            )
        return noise.to(device=self.device, dtype=self.dtype)

    @staticmethod
    def _generators(
        n: int, generator: GeneratorArg, seeds: Sequence[int] | None
    ) -> torch.Generator | list[torch.Generator] | None:
        if seeds is not None:
            if generator is not None:
                raise ConfigError("Pass either `generator` or `seeds`, not both.")
            if len(seeds) != n:
                raise ConfigError(
                    f"`seeds` has {len(seeds)} entries; expected one per image ({n})."
                )
            return [torch.Generator("cpu").manual_seed(int(s)) for s in seeds]
        if generator is None or isinstance(generator, torch.Generator):
            return generator
        gens = list(generator)
        if len(gens) != n:
            raise ConfigError(
                f"`generator` is a list of {len(gens)}; expected one per image ({n})."
            )
        return gens

    @torch.no_grad()
    def sample(
        self,
        encoded: EncodedConditions,
        sampling: SamplingConfig | None = None,
        *,
        num_images_per_condition: int = 1,
        generator: GeneratorArg = None,
        seeds: Sequence[int] | None = None,
        latents: Float[Tensor, "N 4 h w"] | None = None,
        callback: StepCallback | None = None,
    ) -> RelightOutput:
        """Denoise from noise to relit images, conditioned on already-encoded conditions.

        Args:
            encoded: `B` encoded conditions (from `encode`).
            sampling: steps, guidance, scheduler, ...; None for the paper's settings.
            num_images_per_condition: K samples (seeds) per condition, N = B x K.
            generator: one generator or N generators for the initial noise (and DDIM eta > 0).
            seeds: N integer seeds instead of `generator`.
            latents: `[N, 4, h, w]` initial noise instead of drawing it.
            callback: called as `callback(step_index, num_steps)` after every step.

        Returns:
            `RelightOutput` with `[N, 3, H, W]` images in [0, 1].

        Raises:
            NonFiniteOutputError: on NaN/Inf output with `sampling.nonfinite == "raise"`.
            ConfigError: when the number of seeds/generators/latents does not match N.
        """
        sampling = sampling or SamplingConfig()
        if num_images_per_condition < 1:
            raise ConfigError(
                f"`num_images_per_condition` is {num_images_per_condition}; expected >= 1."
            )
        enc = encoded.to(device=self.device, dtype=self.dtype)
        if num_images_per_condition > 1:
            enc = enc.repeat_interleave(num_images_per_condition)
        n = enc.batch_size
        gens = self._generators(n, generator, seeds)
        if sampling.average_samples > 1:
            return self._sample_mean(enc, sampling, gens, latents, callback)
        if latents is None:
            latents = self.initial_noise(n, generator=gens)
        elif tuple(latents.shape) != (n, 4, *enc.image_latents.shape[2:]):
            raise ConfigError(
                f"`latents` has shape {tuple(latents.shape)}; expected "
                f"{(n, 4, *enc.image_latents.shape[2:])}."
            )
        z_T = latents.to(device=self.device, dtype=self.dtype)
        z_0, images = _denoise(self.model, self._unet, enc, z_T, sampling, gens, callback)

        bad = sorted(set(_nonfinite_items(z_0)) | set(_nonfinite_items(images)))
        if bad and sampling.nonfinite == "raise":
            raise NonFiniteOutputError("sampled latents or decoded images", self.dtype, bad)
        if bad:
            logger.warning("NaN/Inf in items %s (%s); rerunning them in float32", bad, self.dtype)
            fp32 = self._fp32_model()
            sub_gens = [gens[i] for i in bad] if isinstance(gens, list) else gens
            z_fix, img_fix = _denoise(
                fp32,
                fp32.unet,
                enc.select(bad).to(dtype=torch.float32),
                z_T[bad].float(),
                sampling,
                sub_gens,
                None,
            )
            still = _nonfinite_items(img_fix)
            if still:
                raise NonFiniteOutputError("float32 retry", torch.float32, [bad[i] for i in still])
            z_0 = z_0.clone()
            z_0[bad] = z_fix.to(z_0.dtype)
            images = images.clone()
            images[bad] = img_fix
        return RelightOutput(images=images, latents=z_0, retried_in_fp32=tuple(bad))

    # The sampler's parts, public so that guidance from 3D (gaffer-nerf's Stage 2 targets and SDS,
    # paper §3.3) runs the same loop, guidance and decoding as `sample` instead of its own copy.

    @property
    def num_train_timesteps(self) -> int:
        """T, the number of training timesteps (1000 for the paper's model)."""
        return int(self.model.config.scheduler.num_train_timesteps)

    def _train_schedule(self) -> Sampler:
        if self._noise_schedule is None:
            self._noise_schedule = make_scheduler("ddim", self.model.config.scheduler)
        return self._noise_schedule

    def alpha_bar(self, t: Tensor) -> Tensor:
        """alpha_bar_t of the model's noise schedule at integer timesteps `t`, on the pipeline's
        device and dtype."""
        bars = cast(Tensor, self._train_schedule().alphas_cumprod)  # type: ignore[attr-defined]
        return bars.to(self.device)[t.to(self.device).long()].to(self.dtype)

    def add_noise(
        self, z0: Float[Tensor, "N 4 h w"], noise: Float[Tensor, "N 4 h w"], t: Tensor
    ) -> Float[Tensor, "N 4 h w"]:
        """z_t ~ q(z_t | z_0) = sqrt(alpha_bar_t) z_0 + sqrt(1 - alpha_bar_t) noise, one t per item."""
        sched = self._train_schedule()
        return sched.add_noise(z0, noise, _int_tensor(t))  # type: ignore[union-attr]

    def predict_noise(
        self,
        z_t: Float[Tensor, "N 4 h w"],
        t: Tensor,
        encoded: EncodedConditions,
        *,
        guidance_scale: float = 1.0,
        as_epsilon: bool = False,
    ) -> Float[Tensor, "N 4 h w"]:
        """The model's classifier-free-guided prediction at noisy latents `z_t` and timestep `t`,
        as every sampling step makes it (unconditional branch: CLIP and the 3 latents zeroed).

        Args:
            z_t: noisy diffusion latents (`add_noise`).
            t: the timestep (a 0-d or one-element integer tensor).
            encoded: the items' conditions (`encode`).
            guidance_scale: s in eps_u + s (eps_c - eps_u); 1 is one conditional pass.
            as_epsilon: convert a v- or sample-prediction to the noise estimate eps_hat (SDS
                needs eps_hat whatever the model predicts).

        Returns:
            The prediction (the UNet's own kind, or eps_hat with `as_epsilon`). Not under
            `no_grad`: callers decide.
        """
        enc = encoded.to(device=self.device, dtype=self.dtype)
        z = z_t.to(device=self.device, dtype=self.dtype)
        t = t.to(self.device)
        pred = _guided_prediction(self._unet, z, t, enc, float(guidance_scale))
        if as_epsilon:
            pred = _as_epsilon(
                pred, z, self.alpha_bar(t), self.model.config.scheduler.prediction_type
            )
        return pred

    def encode_images(
        self,
        images: Float[Tensor, "N 3 H W"],
        encoded: EncodedConditions,
        *,
        latent_mode: LatentMode = "mode",
        generator: torch.Generator | None = None,
    ) -> Float[Tensor, "N 4 h w"]:
        """The diffusion latents z_0 of images in [0, 1] (differentiable w.r.t. `images`): E(x)
        scaled for the paper's model, E(x) - E(input) scaled for a residual one such as gaffer-tiny,
        whose input latents `encoded` holds (`NeuralGafferModel.diffusion_target`)."""
        x = (images * 2.0 - 1.0).to(device=self.device, dtype=self.dtype)
        dist = vae_posterior(self.model.vae, x)
        z = dist.mode() if latent_mode == "mode" else dist.sample(generator=generator)
        return self.model.diffusion_target(z, encoded.image_latents.to(z))

    def decode_latents(
        self, z0: Float[Tensor, "N 4 h w"], encoded: EncodedConditions
    ) -> Float[Tensor, "N 3 H W"]:
        """Images in [0, 1] (float32) from diffusion latents z_0, as `sample` decodes them."""
        return _decode(self.model, z0, encoded)

    def img2img_timesteps(
        self, t_start: float, sampling: SamplingConfig | None = None
    ) -> tuple[Sampler, Tensor]:
        """The scheduler and the timesteps `denoise_from(t_start)` runs.

        The steps of the `sampling.num_inference_steps` schedule at or below t_start x T; when
        it has none there (a few-step model such as gaffer-tiny, whose one step is at t = 999),
        one step from t_start x T itself (never from above, which would discard the image).
        """
        sampling = sampling or self.default_sampling.sampling_config()
        if not 0.0 < t_start <= 1.0:
            raise ConfigError(
                f"`t_start` is {t_start!r}; expected a fraction of the training timesteps in (0, 1]."
            )
        sched = make_scheduler(
            sampling.scheduler,
            self.model.config.scheduler,
            timestep_spacing=sampling.timestep_spacing,
        )
        sched.set_timesteps(sampling.num_inference_steps, device=self.device)
        ts = sched.timesteps
        limit = t_start * self.num_train_timesteps
        below = ts[ts <= limit]
        if below.numel() > 0:
            return sched, below
        start = max(1, round(limit))  # every schedule step lies above t_start
        return sched, torch.tensor([start], dtype=ts.dtype, device=ts.device)

    @torch.no_grad()
    def denoise_from(
        self,
        images: Float[Tensor, "B 3 H W"],
        t_start: float,
        encoded: EncodedConditions,
        sampling: SamplingConfig | None = None,
        *,
        generator: torch.Generator | None = None,
        latent_mode: LatentMode = "mode",
        noise: Float[Tensor, "N 4 h w"] | None = None,
        mirrored: EncodedConditions | None = None,
    ) -> Float[Tensor, "B 3 H W"]:
        """Image-to-image (SDEdit, paper §3.3 Eq. 3; diffusers' `strength`): encode `images`,
        noise them to t_start, denoise with `sample`'s loop and guidance, decode.

        With `sampling.average_samples` K the mean of K noises; with `mirrored` (the items'
        conditions under the mirrored lighting) also the mirrored images under them with the same
        noise, flipped back and averaged.

        Args:
            images: `[B, 3, H, W]` in [0, 1] at the model resolution.
            t_start: where to start, a fraction of the training timesteps (`img2img_timesteps`).
            encoded: the items' conditions (`encode`).
            sampling: steps, guidance, scheduler; None: `default_sampling`.
            generator: one RNG for the posterior sample (`latent_mode="sample"`) and then the noise.
            latent_mode: how `images` are encoded: the VAE posterior's "mode" or a "sample".
            noise: `[B * K, 4, h, w]` noise (item-major) instead of drawing it.
            mirrored: the mirrored conditions for the mirror mean, or None.

        Returns:
            `[B, 3, H, W]` float32 images in [0, 1].
        """
        sampling = sampling or self.default_sampling.sampling_config()
        b, k = images.shape[0], sampling.average_samples
        enc = encoded.to(device=self.device, dtype=self.dtype).repeat_interleave(k)
        x = images.repeat_interleave(k, dim=0)
        if mirrored is not None:
            m = mirrored.to(device=self.device, dtype=self.dtype).repeat_interleave(k)
            enc = EncodedConditions.cat([enc, m])
            x = torch.cat([x, x.flip(-1)])
        sched, ts = self.img2img_timesteps(t_start, sampling)
        z0 = self.encode_images(x, enc, latent_mode=latent_mode, generator=generator)
        if noise is None:
            noise = torch.randn((b * k, *z0.shape[1:]), generator=generator, dtype=torch.float32)
        elif tuple(noise.shape) != (b * k, *z0.shape[1:]):
            raise ConfigError(
                f"`noise` has shape {tuple(noise.shape)}; expected {(b * k, *z0.shape[1:])}."
            )
        if mirrored is not None:
            noise = torch.cat([noise, noise])
        noise = noise.to(device=z0.device, dtype=z0.dtype)
        z = sched.add_noise(z0, noise, _int_tensor(ts[:1].repeat(z0.shape[0])))  # type: ignore[union-attr]
        _, out = _denoise(self.model, self._unet, enc, z, sampling, None, None, start=(sched, ts))
        if mirrored is not None:
            out = (out[: b * k] + out[b * k :].flip(-1)) / 2.0
        return out.unflatten(0, (b, k)).mean(dim=1)

    def _sample_mean(
        self,
        enc: EncodedConditions,
        sampling: SamplingConfig,
        gens: torch.Generator | list[torch.Generator] | None,
        latents: Tensor | None,
        callback: StepCallback | None,
    ) -> RelightOutput:
        """`sampling.average_samples` = K samples per item in one batch, averaged per item."""
        k, n = sampling.average_samples, enc.batch_size
        h = self.model.config.latent_size
        shape = (k, self.model.config.vae.latent_channels, h, h)
        if latents is not None:
            if tuple(latents.shape) != (n * k, *shape[1:]):
                raise ConfigError(
                    f"`latents` has shape {tuple(latents.shape)}; with `average_samples` {k} "
                    f"expected {(n * k, *shape[1:])} (K noises per item, item-major)."
                )
            noise = latents
        elif isinstance(gens, list):  # K noises in turn from each item's own generator
            noise = torch.cat([torch.randn(shape, generator=g, device=g.device) for g in gens])
        else:
            noise = self.initial_noise(n * k, generator=gens)
        out = self.sample(
            enc.repeat_interleave(k),
            dataclasses.replace(sampling, average_samples=1),
            latents=noise.to(device=self.device, dtype=self.dtype),
            callback=callback,
        )
        images = out.images.unflatten(0, (n, k)).mean(dim=1)
        latents_mean = out.latents.unflatten(0, (n, k)).mean(dim=1)
        retried = tuple(sorted({i // k for i in out.retried_in_fp32}))
        return RelightOutput(images=images, latents=latents_mean, retried_in_fp32=retried)

    def __call__(
        self,
        conditions: RelightingConditions,
        sampling: SamplingConfig | None = None,
        *,
        num_images_per_condition: int = 1,
        generator: GeneratorArg = None,
        seeds: Sequence[int] | None = None,
        callback: StepCallback | None = None,
    ) -> RelightOutput:
        """Encode `conditions` and sample (see `encode` and `sample`).

        With `conditions.mask`, the output keeps the input outside the object (see
        `RelightingConditions`), and with `sampling.mirror_average` it is the mean of the
        prediction and the mirrored input's prediction flipped back; `sample` alone does neither.
        """
        sampling = sampling or SamplingConfig()
        if sampling.mirror_average:
            return self._mirror_mean(
                conditions, sampling, num_images_per_condition, generator, seeds, callback
            )
        enc_gen = self._posterior_generators(
            conditions.batch_size, sampling, num_images_per_condition, generator, seeds
        )
        encoded = self.encode(conditions, latent_mode=sampling.latent_mode, generator=enc_gen)
        out = self.sample(
            encoded,
            sampling,
            num_images_per_condition=num_images_per_condition,
            generator=generator,
            seeds=seeds,
            callback=callback,
        )
        if conditions.mask is None:
            return out
        k = num_images_per_condition
        x = conditions.image.to(out.images.device, torch.float32).repeat_interleave(k, dim=0)
        m = conditions.mask.to(out.images.device, torch.float32).repeat_interleave(k, dim=0)
        # lerp keeps NaN from the model, so the finiteness checks downstream still see it
        return dataclasses.replace(out, images=torch.lerp(x, out.images, m))

    def _posterior_generators(
        self,
        batch_size: int,
        sampling: SamplingConfig,
        k: int,
        generator: GeneratorArg,
        seeds: Sequence[int] | None,
    ) -> torch.Generator | list[torch.Generator] | None:
        """RNG of the posterior samples of `latent_mode="sample"` (the authors draw them from
        the sampling seed; our reading of their inference script).

        The authors hand one seeded generator per item to their pipeline, which draws the initial
        noise and then the posterior samples from it. With `seeds`, each condition gets a CPU
        generator seeded with its (first output's) seed and advanced past that output's initial
        noise, so the posterior noise continues the noise's stream, is independent of the batch and
        reproducible, and `latent_mode="mode"` with the same seed starts from the same z_T. With
        `generator` the posterior noise is drawn from it (per item for a list) before the initial
        noise. Nothing for `latent_mode="mode"`.
        """
        if sampling.latent_mode == "mode":
            return None
        if seeds is not None:
            if len(seeds) != batch_size * k:
                raise ConfigError(
                    f"`seeds` has {len(seeds)} entries; expected one per image ({batch_size * k})."
                )
            gens = [
                torch.Generator("cpu").manual_seed(int(seeds[b * k])) for b in range(batch_size)
            ]
            self.initial_noise(batch_size, generator=gens)  # advance each stream past its z_T
            return gens
        if generator is None or isinstance(generator, torch.Generator):
            return generator
        gens = list(generator)
        if len(gens) != batch_size * k:
            raise ConfigError(
                f"`generator` is a list of {len(gens)}; expected one per image ({batch_size * k})."
            )
        return gens[::k]

    def _mirror_mean(
        self,
        conditions: RelightingConditions,
        sampling: SamplingConfig,
        num_images_per_condition: int,
        generator: GeneratorArg,
        seeds: Sequence[int] | None,
        callback: StepCallback | None,
    ) -> RelightOutput:
        """`SamplingConfig.mirror_average`: the B items and their mirrors in one batch of 2B."""
        from gaffer_envmap.augment import mirror_camera_x

        c = conditions
        both = RelightingConditions(
            image=torch.cat([c.image, c.image.flip(-1)]),
            lighting=LightingMaps(
                ldr=torch.cat([c.lighting.ldr, mirror_camera_x(c.lighting.ldr)]),
                hdr=torch.cat([c.lighting.hdr, mirror_camera_x(c.lighting.hdr)]),
            ),
            mask=None if c.mask is None else torch.cat([c.mask, c.mask.flip(-1)]),
            normals=None
            if c.normals is None
            else torch.cat([c.normals, _mirror_normals(c.normals)]),
        )
        if not (generator is None or isinstance(generator, torch.Generator)):
            generator = list(generator) * 2  # the mirrors draw next from the same generators
        out = self(
            both,
            dataclasses.replace(sampling, mirror_average=False),
            num_images_per_condition=num_images_per_condition,
            generator=generator,
            seeds=None if seeds is None else [*seeds, *seeds],
            callback=callback,
        )
        n = out.images.shape[0] // 2
        images = (out.images[:n] + out.images[n:].flip(-1)) / 2.0
        retried = tuple(sorted({i % n for i in out.retried_in_fp32}))
        return RelightOutput(images=images, latents=out.latents[:n], retried_in_fp32=retried)

    def _fp32_model(self) -> NeuralGafferModel:
        if self.dtype == torch.float32:
            return self.model
        if self._fp32 is None:
            m = self.model
            self._fp32 = type(m)(
                config=m.config,
                unet=copy.deepcopy(m.unet).float(),
                vae=copy.deepcopy(m.vae).float(),
                image_encoder=m.image_encoder,
            )
        return self._fp32


if TYPE_CHECKING:
    _IntTensor = torch.IntTensor
else:  # at run time an int64 tensor: no tensor is an instance of the legacy class (see below)
    _IntTensor = Tensor


def _int_tensor(timesteps: Tensor) -> _IntTensor:
    """`timesteps` as diffusers' `add_noise` annotates them: the legacy `torch.IntTensor` class, which
    no tensor is an instance of (it takes any integer tensor; the schedule's are int64)."""
    return cast(torch.IntTensor, timesteps)


def _under_autocast(
    unet: Callable[..., object], device_type: str, dtype: torch.dtype
) -> Callable[..., object]:
    """`unet` called under `torch.autocast(device_type, dtype)`: float32 weights, low-precision
    matmuls and convolutions (the authors' fp16 UNet, official implementation §2)."""

    def call(*args: object, **kwargs: object) -> object:
        with torch.autocast(device_type=device_type, dtype=dtype):
            return unet(*args, **kwargs)

    return call


def _step(
    scheduler: Sampler,
    eps: Tensor,
    t: Tensor,
    z: Tensor,
    *,
    eta: float,
    generator: torch.Generator | list[torch.Generator] | None,
) -> Tensor:
    """One reverse step z_t -> z_{t-1} (`scheduler.step(...).prev_sample`); `eta` and `generator` go to
    DDIM only (the multistep solvers take neither)."""
    # diffusers annotates `timestep` as int (it takes the schedule's 0-d tensors) and DDIM's `generator`
    # as one Generator (randn_tensor takes a list, one per item): the casts only restate what runs
    timestep = cast(int, t)
    if isinstance(scheduler, DDIMScheduler):
        gen = cast(torch.Generator | None, generator)
        out = scheduler.step(eps, timestep, z, eta=eta, generator=gen)
    else:
        out = scheduler.step(eps, timestep, z)
    # a SchedulerOutput (return_dict=True, the default); the bare `(prev_sample,)` tuple never comes here
    return out[0] if isinstance(out, tuple) else out.prev_sample


def _guided_prediction(
    unet: Callable[..., object], z: Tensor, t: Tensor, enc: EncodedConditions, guidance_scale: float
) -> Tensor:
    """The UNet's prediction at `z` (already `scale_model_input`-ed), timestep `t`, with
    classifier-free guidance: the unconditional branch zeroes the CLIP embedding AND the three
    conditioning latents (official implementation §2); guidance 1 is one conditional pass."""
    cond = enc.concat_latents()  # [N, 12, h, w]  E(x), E(E_H), E(E_L)
    context = enc.clip_embeds  # [N, 1, D]
    if guidance_scale == 1.0:  # eps = eps_cond exactly (SamplingConfig.do_classifier_free_guidance)
        unet_in = torch.cat([z, cond], dim=1)  # [N, 16, h, w]  z_t + 3x4 conditioning latents
        return unet(unet_in, t, encoder_hidden_states=context).sample  # type: ignore[attr-defined]
    unet_in = torch.cat([torch.cat([z, z]), torch.cat([cond, torch.zeros_like(cond)])], dim=1)
    context = torch.cat([context, torch.zeros_like(context)])  # [2N, 1, D]
    eps = unet(unet_in, t, encoder_hidden_states=context).sample  # type: ignore[attr-defined]
    eps_c, eps_u = eps.chunk(2)
    return eps_u + guidance_scale * (eps_c - eps_u)


def _denoise(
    model: NeuralGafferModel,
    unet: Callable[..., object],
    enc: EncodedConditions,
    z_T: Tensor,
    sampling: SamplingConfig,
    generator: torch.Generator | list[torch.Generator] | None,
    callback: StepCallback | None,
    start: tuple[Sampler, Tensor] | None = None,
) -> tuple[Tensor, Tensor]:
    """The sampling loop and decode, the one every path runs (`sample`, `denoise_from`).

    From pure noise `z_T` over the whole schedule, or with `start` = (scheduler, its timesteps at
    or below t*) from latents `z_T` already noised to the first of them (SDEdit, paper §3.3).
    Returns (final latents [N,4,h,w], images [N,3,H,W] float32).
    """
    if start is None:
        scheduler = make_scheduler(
            sampling.scheduler, model.config.scheduler, timestep_spacing=sampling.timestep_spacing
        )
        scheduler.set_timesteps(sampling.num_inference_steps, device=z_T.device)
        timesteps = scheduler.timesteps
        z = z_T * scheduler.init_noise_sigma
    else:
        (scheduler, timesteps), z = start, z_T
    for i, t in enumerate(timesteps):
        z_in = scheduler.scale_model_input(z, cast(int, t))  # a 0-d tensor, typed int upstream
        eps = _guided_prediction(unet, z_in, t, enc, sampling.guidance_scale)
        z = _step(scheduler, eps, t, z, eta=sampling.eta, generator=generator)
        if callback is not None:
            callback(i, len(timesteps))
    return z, _decode(model, z, enc)


def _decode(model: NeuralGafferModel, z: Tensor, enc: EncodedConditions) -> Tensor:
    """Images in [0, 1] (float32) from diffusion latents z_0 (`NeuralGafferModel.decodable_latents`)."""
    decoded = vae_decode(model.vae, model.decodable_latents(z, enc.image_latents.to(z)))
    images = (decoded.float() / 2.0 + 0.5).clamp(0.0, 1.0)
    # clamp keeps NaN, so the caller's finiteness check still sees them
    return torch.where(torch.isfinite(decoded.float()), images, decoded.float())


def _as_epsilon(pred: Tensor, z_t: Tensor, alpha_bar: Tensor, prediction_type: str) -> Tensor:
    """The UNet's output as a noise estimate, whatever it predicts."""
    if prediction_type == "v_prediction":  # v = sqrt(abar) eps - sqrt(1 - abar) z_0
        return alpha_bar.sqrt() * pred + (1.0 - alpha_bar).sqrt() * z_t
    if prediction_type == "sample":  # z_t = sqrt(abar) z_0 + sqrt(1 - abar) eps
        return (z_t - alpha_bar.sqrt() * pred) / (1.0 - alpha_bar).sqrt()
    return pred


def _mirror_normals(normals: Tensor) -> Tensor:
    """Camera-frame normals of the mirrored image: flipped left-right, x negated."""
    sign = torch.tensor([-1.0, 1.0, 1.0], device=normals.device, dtype=normals.dtype)
    return normals.flip(-1) * sign.view(1, 3, 1, 1)
