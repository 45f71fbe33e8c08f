"""Settings of one sampling call (`SamplingConfig`), in a module that imports neither torch nor diffusers.

`DefaultSampling.sampling_config` (read by the command line before torch loads) and the pipelines both
build it from here; `gaffer_diffusion.pipelines.config` re-exports it beside `RuntimeConfig`.
"""

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

from gaffer_diffusion._choices import MULTISTEP_SCHEDULERS, SCHEDULERS, LatentMode, SchedulerName
from gaffer_diffusion.errors import ConfigError

__all__ = ["NonFinitePolicy", "SamplingConfig"]

NonFinitePolicy = Literal["raise", "retry_fp32"]
"""What to do when sampling yields NaN/Inf: raise `NonFiniteOutputError` (default) or rerun the affected
items in float32 from the same initial noise (a float32 copy of the networks is made once, lazily)."""

if TYPE_CHECKING:
    _SchedulerArg = SchedulerName
else:  # at run time any str reaches `SamplingConfig`, which refuses an unknown one
    _SchedulerArg = str


@dataclass(frozen=True, kw_only=True)
class SamplingConfig:
    """Settings of one sampling call. The defaults are the paper's (official implementation §2).

    Attributes:
        num_inference_steps: denoising steps (50).
        guidance_scale: classifier-free guidance scale s (3.0); 1.0 skips the unconditional branch.
        scheduler: "ddim" (the paper's), "dpmpp-2m" (DPM-Solver++ 2M; "dpmsolver++" is its earlier
            spelling) or "unipc"; the multistep two need >= 2 steps and eta 0.
        eta: DDIM eta (0: deterministic); refused with the multistep solvers.
        timestep_spacing: override the schedule's "leading" spacing (e.g. "trailing" for few steps).
        latent_mode: conditioning latents from the VAE posterior "mode" (default) or a "sample".
        nonfinite: what to do on NaN/Inf output (see `NonFinitePolicy`).
        average_samples: K > 1 returns, per output, the mean image of K samples from K independent
            initial noises (drawn in turn from the item's own generator or seed). With one step from
            t = T this is a Monte-Carlo estimate of the posterior mean E[target | conditions], the
            prediction with the least expected squared error (best PSNR), at K times the cost; the
            samples themselves are sharper but each carries its own noise. Needs `eta` = 0. (1).
        mirror_average: also relight the input flipped left-right under the lighting mirrored in
            camera x (`gaffer_envmap.augment.mirror_camera_x`), flip that back and return the mean
            of the two: relighting commutes with the mirror, so the two predictions err
            differently and their mean errs less (test-time augmentation; 2x the cost; only
            through `RelightPipeline.__call__`). Off by default (the paper does not do it).

    Raises:
        ConfigError: on out-of-range values.
    """

    num_inference_steps: int = 50
    guidance_scale: float = 3.0
    scheduler: _SchedulerArg = "ddim"
    eta: float = 0.0
    timestep_spacing: Literal["leading", "trailing", "linspace"] | None = None
    latent_mode: LatentMode = "mode"
    nonfinite: NonFinitePolicy = "raise"
    average_samples: int = 1
    mirror_average: bool = False

    def __post_init__(self) -> None:
        if (
            not isinstance(self.num_inference_steps, int)
            or not 1 <= self.num_inference_steps <= 1000
        ):
            raise ConfigError(
                f"`num_inference_steps` (--steps) is {self.num_inference_steps!r}; expected an int in [1, 1000]."
            )
        if not math.isfinite(self.guidance_scale) or self.guidance_scale < 0:
            raise ConfigError(
                f"`guidance_scale` (--guidance) is {self.guidance_scale!r}; expected a finite value >= 0 (paper: 3)."
            )
        if not 0.0 <= self.eta <= 1.0:
            raise ConfigError(f"`eta` is {self.eta!r}; expected a value in [0, 1].")
        if self.scheduler not in SCHEDULERS:
            raise ConfigError(
                f"`scheduler` is {self.scheduler!r}; expected one of {list(SCHEDULERS)}."
            )
        if self.scheduler in MULTISTEP_SCHEDULERS and self.num_inference_steps < 2:
            raise ConfigError(
                f"`scheduler` {self.scheduler!r} with {self.num_inference_steps} step: a multistep "
                "solver needs >= 2 steps (15-25 is its range); pass `--steps 20`, or `--scheduler "
                "ddim` for one step."
            )
        if self.scheduler in MULTISTEP_SCHEDULERS and self.eta != 0.0:
            raise ConfigError(
                f"`eta` is {self.eta} with `scheduler` {self.scheduler!r}: eta is DDIM's noise "
                "level and the multistep solvers are deterministic; set eta=0 or use 'ddim'."
            )
        if self.latent_mode not in ("mode", "sample"):
            raise ConfigError(
                f"`latent_mode` is {self.latent_mode!r}; expected 'mode' or 'sample'."
            )
        if self.nonfinite not in ("raise", "retry_fp32"):
            raise ConfigError(
                f"`nonfinite` is {self.nonfinite!r}; expected 'raise' or 'retry_fp32'."
            )
        if not isinstance(self.average_samples, int) or self.average_samples < 1:
            raise ConfigError(
                f"`average_samples` (--average-samples) is {self.average_samples!r}; expected an int >= 1."
            )
        if self.average_samples > 1 and self.eta != 0.0:
            raise ConfigError(
                f"`average_samples` is {self.average_samples} with `eta` {self.eta}: averaging "
                "needs deterministic sampling; set eta=0."
            )

    @property
    def do_classifier_free_guidance(self) -> bool:
        """False only for guidance 1, where eps = eps_cond exactly and one UNet pass suffices."""
        return self.guidance_scale != 1.0
