"""The pack's custom ComfyUI types, frozen dataclasses passed between nodes (never dicts of tensors).

- `GAFFER_MODEL` (`GafferModel`): a loaded relighting model, its sampling pipeline and the sampling
  the model suggests for itself (its folder's `suggested_sampling`, as every gaffer command reads it).
- `GAFFER_ENVMAP` (`GafferEnvmap`): an equirectangular environment map as linear scene-referred HDR
  float32 (`gaffer_envmap.EnvironmentMap`, Blender convention, `We == 2 He`). It never travels as a
  clipped 8-bit IMAGE: the sun of a map is thousands of times brighter than 1.0 and the model's HDR
  lighting encoding needs that energy (Neural Gaffer §3.2, E_H). Its previews are separate IMAGEs.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import NodeInputError

if TYPE_CHECKING:
    from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
    from gaffer_diffusion.suggested import SuggestedSampling
    from gaffer_envmap import EnvironmentMap

__all__ = ["GAFFER_ENVMAP", "GAFFER_MODEL", "GafferEnvmap", "GafferModel"]

GAFFER_MODEL = "GAFFER_MODEL"
"""ComfyUI type name of a `GafferModel`."""

GAFFER_ENVMAP = "GAFFER_ENVMAP"
"""ComfyUI type name of a `GafferEnvmap`."""


@dataclass(frozen=True, kw_only=True, eq=False)
class GafferModel:
    """A relighting model ready to sample.

    Attributes:
        pipe: the sampling pipeline (`gaffer_diffusion.RelightPipeline`) on its device.
        name: a label ("gaffer-tiny", or the model's config name).
        source: the folder the weights came from.
        suggested: how the model is meant to be sampled (steps, guidance, averaging, lighting
            encoding), read from its folder as `gaffer-diffusion relight` reads it.
    """

    pipe: "RelightPipeline"
    name: str
    source: Path
    suggested: "SuggestedSampling"

    @property
    def size(self) -> int:
        """The model's square input and output side, pixels (gaffer-tiny: 128)."""
        return int(self.pipe.model.config.resolution)

    @property
    def compat(self) -> Any:
        """The lighting encoding and framing the model was trained with ("default" or "neural-gaffer")."""
        return self.suggested.compat

    def sampling(self, steps: int, guidance: float) -> "SamplingConfig":
        """DDIM settings as `gaffer-diffusion relight` builds them: `steps` (0: the model's own) and
        `guidance` (negative: the model's own), the model's averaging, and the authors' posterior
        sample for the "neural-gaffer" encoding (else the posterior mode)."""
        from gaffer_diffusion.pipelines import SamplingConfig

        own = self.suggested
        return SamplingConfig(
            num_inference_steps=own.num_inference_steps if steps == 0 else int(steps),
            guidance_scale=float(own.guidance_scale if guidance < 0 else guidance),
            scheduler="ddim",
            average_samples=own.average_samples,
            mirror_average=bool(own.mirror_average),
            latent_mode="sample" if own.compat == "neural-gaffer" else "mode",
        )


@dataclass(frozen=True, kw_only=True, eq=False)
class GafferEnvmap:
    """An HDR environment map between nodes.

    Attributes:
        envmap: `gaffer_envmap.EnvironmentMap`: `[He, 2 He, 3]` float32 linear radiance, Blender
            convention (z up, row 0 the +up pole), finite and non-negative.
        label: what it is, for messages ("courtyard", a file name, a phrase, "... rotated").

    Raises:
        NodeInputError: a map that is not float32, not Blender-convention, or holds NaN, Inf or
            negative radiance.
    """

    envmap: "EnvironmentMap"
    label: str

    def __post_init__(self) -> None:
        rad = self.envmap.radiance_linear
        if rad.dtype != np.float32:
            raise NodeInputError(
                f"GAFFER_ENVMAP {self.label!r} holds {rad.dtype}; it must be float32 linear radiance."
            )
        if self.envmap.convention != "blender":
            raise NodeInputError(
                f"GAFFER_ENVMAP {self.label!r} is in the {self.envmap.convention!r} convention; "
                "convert it to 'blender' (gaffer_envmap.convert_convention) first."
            )
        if not bool(np.isfinite(rad).all()) or bool((rad < 0).any()):
            raise NodeInputError(
                f"GAFFER_ENVMAP {self.label!r} holds NaN, Inf or negative radiance; load it with "
                "`sanitize` 'zero' or 'clamp'."
            )

    @property
    def radiance_linear(self) -> np.ndarray:
        """`[He, 2 He, 3]` float32 linear radiance (read-only)."""
        return self.envmap.radiance_linear
