"""What the demo relights and how: `DemoConfig`, and the sampling defaults it checks against."""

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from gaffer_diffusion.conditioning import CompatMode
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.evaluation import InputLighting
from gaffer_diffusion.pipelines import SamplingConfig
from gaffer_diffusion.runtime_dtype import DTYPE_REQUESTS, DtypeRequest
from gaffer_envmap.compat_mode import compat_problem
from gaffer_envmap.sanitize import SANITIZE_POLICIES, SanitizePolicy

DEFAULT_STEPS = 50
"""Denoising steps when neither `num_inference_steps` nor the model suggests a number (paper: 50)."""


DEFAULT_GUIDANCE = 3.0
"""Guidance scale when neither `guidance_scale` nor the model suggests one (paper: 3)."""


InputChoice = InputLighting | Literal["auto"]
"""The input render of the example view: a lighting index, "area", or "auto" (area when rendered)."""


@dataclass(frozen=True, kw_only=True)
class DemoConfig:
    """What `run_demo` relights and how.

    Attributes:
        out: output folder (created if missing; files already there are overwritten).
        checkpoint: a model folder in our format (`gaffer_model.json`); None: gaffer-tiny.
        example: a gaffer-data render folder; None: the shipped example
            (`gaffer_diffusion.pretrained.example_dataset_path()`).
        input_lighting: which render of the view is the input ("auto": the area-light render when
            there is one, else lighting 0).
        num_inference_steps: denoising steps; None: the model's suggestion (gaffer-tiny: 1), else 50.
        guidance_scale: classifier-free guidance scale; None: the model's suggestion (gaffer-tiny: 1,
            no unconditional branch), else 3 (the paper's).
        average_samples: samples averaged per image (`SamplingConfig.average_samples`); None: the
            model's suggestion, else 1.
        mirror_average: average with the mirrored input (`SamplingConfig.mirror_average`); None:
            the model's suggestion, else off.
        frames: turntable frames (0: no turntable).
        turntable_hdri: the bundled HDRI the turntable spins; None: the one whose diffuse light
            changes most when spun about up (`gaffer_envmap.directionality(about_up=True)`), since
            under a sky that is nearly the same from every side even a perfect model's turntable
            would stand still.
        fps: turntable GIF frames per second.
        seed: the initial-noise seed of every image.
        batch_size: images per sampling call.
        device: torch device string.
        dtype: the networks' precision, as `gaffer-diffusion relight --dtype` takes it ("auto", the
            default there too: bfloat16 on a CPU with native bf16 for a 100M+ parameter UNet, else
            float32, so gaffer-tiny runs in float32; the report records the dtype used).
        compat: gaffer-envmap lighting encoding; None: the model's own (gaffer-tiny: "default"),
            else "neural-gaffer" (the released checkpoint's).
        object_fraction: crop the example view around its object, which then spans this fraction
            of the side (`gaffer_diffusion.preprocess.object_square`); None: the model's own
            framing (gaffer-tiny: 0.75), else the whole render. 1.0 still crops to the object.
        extra_hdris: also relight under the bundled HDRIs that have no ground-truth render.
        keep_background: keep the input outside its alpha (`RelightingConditions.mask`); False:
            the model's full frame.
        sanitize: NaN/Inf/negative pixels of the `example`'s env maps (`gaffer_envmap.read_envmap`,
            CLI `--sanitize`): "raise" (default: tiny negatives from lossy compression become 0,
            anything else is refused), "strict", "zero" or "clamp". The bundled HDRIs (extra maps,
            turntable) are read as gaffer-envmap ships them (`read_bundled_hdri`).

    Raises:
        ConfigError: on out-of-range values.
    """

    out: Path
    checkpoint: Path | None = None
    example: Path | None = None
    input_lighting: InputChoice = "auto"
    num_inference_steps: int | None = None
    guidance_scale: float | None = None
    average_samples: int | None = None
    mirror_average: bool | None = None
    frames: int = 24
    turntable_hdri: str | None = None
    fps: float = 12.0
    seed: int = 0
    batch_size: int = 8
    device: str = "cpu"
    dtype: DtypeRequest = "auto"
    compat: CompatMode | None = None
    extra_hdris: bool = True
    keep_background: bool = True
    object_fraction: float | None = None
    sanitize: SanitizePolicy = "raise"

    def __post_init__(self) -> None:
        if not isinstance(self.frames, int) or self.frames < 0:
            raise ConfigError(f"`frames` (--frames) is {self.frames!r}; expected an int >= 0.")
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ConfigError(
                f"`batch_size` (--batch-size) is {self.batch_size!r}; expected an int >= 1."
            )
        if not (math.isfinite(self.fps) and self.fps > 0):
            raise ConfigError(f"`fps` (--fps) is {self.fps!r}; expected > 0.")
        # range checks with SamplingConfig's messages
        SamplingConfig(
            num_inference_steps=self.num_inference_steps or DEFAULT_STEPS,
            guidance_scale=DEFAULT_GUIDANCE if self.guidance_scale is None else self.guidance_scale,
            average_samples=self.average_samples or 1,
        )
        if self.dtype not in DTYPE_REQUESTS:
            raise ConfigError(
                f"`dtype` (--dtype) is {self.dtype!r}; expected one of {', '.join(DTYPE_REQUESTS)}."
            )
        if self.sanitize not in SANITIZE_POLICIES:
            raise ConfigError(
                f"`sanitize` (--sanitize) is {self.sanitize!r}; expected one of "
                f"{', '.join(SANITIZE_POLICIES)}."
            )
        if self.compat is not None and (problem := compat_problem("compat", self.compat)):
            raise ConfigError(problem)
        if self.object_fraction is not None and not 0.0 < self.object_fraction <= 1.0:
            raise ConfigError(
                f"`object_fraction` is {self.object_fraction!r}; expected a fraction in (0, 1]."
            )
