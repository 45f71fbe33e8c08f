"""A model's own suggested sampling, stored in its folder's manifest (`gaffer_model.json`).

A model is only right when it is sampled the way it was trained and evaluated: gaffer-tiny with one
DDIM step and gaffer-envmap's "default" lighting encoding, the authors' checkpoint with 50 steps,
guidance 3 and their "neural-gaffer" encoding (official implementation §2). A self-trained model relit
with another model's encoding silently relights wrong, so the setting travels with the weights:
`gaffer-diffusion export` writes it from the training config (the encoding and framing trained with,
the sampler validated with). `gaffer_diffusion.load_pipeline` reads it once (`read_default_sampling`)
into the pipeline's frozen `default_sampling`; every path that samples a model (`relight`, `evaluate`,
`demo`, the app, gaffer-nerf's stages) only overrides it (`DefaultSampling.override`,
`DefaultSampling.sampling_config`).

Reading it is a JSON read (no torch), so commands can check arguments against it before loading weights.
"""

import json
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import CheckpointMismatchError, ConfigError
from gaffer_diffusion.sampling_config import SamplingConfig

__all__ = [
    "PAPER_SAMPLING",
    "PAPER_SUGGESTION",
    "SUGGESTION_KEY",
    "DefaultSampling",
    "LatentModeName",
    "SuggestedSampling",
    "latent_mode_for",
    "read_default_sampling",
    "read_suggested_sampling",
    "suggestion_from_training_config",
]

LatentModeName = Literal["mode", "sample"]
"""Conditioning latents from the VAE posterior's "mode" or a "sample" (`SamplingConfig.latent_mode`)."""


def latent_mode_for(compat: str) -> LatentModeName:
    """The latent mode that goes with a lighting encoding: the authors' posterior "sample" under their
    "neural-gaffer" encoding (their inference, official implementation §2), else the posterior "mode".

    The one place this rule is written; everything that samples a model asks here.

    Example:
        >>> latent_mode_for("neural-gaffer"), latent_mode_for("default")
        ('sample', 'mode')
    """
    return "sample" if compat == "neural-gaffer" else "mode"


SUGGESTION_KEY = "suggested_sampling"
"""The manifest key holding a `DefaultSampling`."""


if TYPE_CHECKING:
    _CompatArg = Literal["neural-gaffer", "default"]
else:  # from a manifest any value reaches `compat`; `__post_init__` names a wrong one (ValueError)
    _CompatArg = object


@dataclass(frozen=True, kw_only=True)
class DefaultSampling:
    """How a model is meant to be sampled: read once from its folder, then only overridden.

    `latent_mode` follows from `compat` (`latent_mode_for`) unless an override names it.

    Attributes:
        num_inference_steps: DDIM steps.
        guidance_scale: classifier-free guidance scale.
        average_samples: samples averaged per output.
        mirror_average: average with the relit mirrored input (`SamplingConfig.mirror_average`).
        compat: the gaffer-envmap lighting encoding the model was trained with.
        object_fraction: the object-centred framing it was trained with (None: whole renders).
        source: where the setting comes from, for logs and reports.
    """

    num_inference_steps: int
    guidance_scale: float | int
    average_samples: int = 1
    mirror_average: bool = False
    compat: _CompatArg = "neural-gaffer"
    object_fraction: float | int | None = None
    source: str = ""

    def __post_init__(self) -> None:
        # the command-line flag of each value in parentheses: an override that is out of range is
        # refused here, naming the flag (a manifest's own block is refused by its reader)
        problems = []
        if not (
            isinstance(self.num_inference_steps, int) and 1 <= self.num_inference_steps <= 1000
        ):
            problems.append(
                f"num_inference_steps (--steps) {self.num_inference_steps!r} (need 1..1000)"
            )
        g = self.guidance_scale
        if not (isinstance(g, int | float) and math.isfinite(g) and g >= 0):
            problems.append(f"guidance_scale (--guidance) {g!r} (need finite >= 0)")
        if not (isinstance(self.average_samples, int) and self.average_samples >= 1):
            problems.append(
                f"average_samples (--average-samples) {self.average_samples!r} (need >= 1)"
            )
        if self.compat not in ("neural-gaffer", "default"):
            problems.append(
                f"compat (--compat) {self.compat!r} (need 'neural-gaffer' or 'default')"
            )
        f = self.object_fraction
        if f is not None and not (isinstance(f, int | float) and 0 < f <= 1):
            problems.append(f"object_fraction (--object-fraction) {f!r} (need (0, 1] or null)")
        if problems:
            raise ConfigError("sampling: " + "; ".join(problems))

    def to_json(self) -> dict[str, Any]:
        """The manifest block (without `source`, which says where a reader found it)."""
        body = asdict(self)
        body.pop("source")
        return body

    def describe(self) -> str:
        """One line, e.g. "1 DDIM step, guidance 1, mirror average, 'default' encoding, latent mode"."""
        steps = self.num_inference_steps
        parts = [
            f"{steps} DDIM step{'s' if steps != 1 else ''}",
            f"guidance {self.guidance_scale:g}",
        ]
        if self.average_samples > 1:
            parts.append(f"mean of {self.average_samples} samples")
        if self.mirror_average:
            parts.append("mirror average")
        parts.append(f"{self.compat!r} encoding")
        parts.append(f"latent {self.latent_mode}")
        if self.object_fraction is not None:
            parts.append(f"object-centred crops ({self.object_fraction:g})")
        return ", ".join(parts)

    @property
    def latent_mode(self) -> LatentModeName:
        """The latent mode that goes with `compat` (`latent_mode_for`)."""
        return latent_mode_for(self.compat)

    def override(
        self,
        *,
        num_inference_steps: int | None = None,
        guidance_scale: float | None = None,
        average_samples: int | None = None,
        mirror_average: bool | None = None,
        compat: _CompatArg | None = None,
        object_fraction: float | None = None,
        source: str | None = None,
    ) -> "DefaultSampling":
        """This setting with every value that is not None replaced (checked as on reading).

        Example:
            >>> PAPER_SAMPLING.override(guidance_scale=2.0).num_inference_steps
            50
        """
        given = {
            "num_inference_steps": num_inference_steps,
            "guidance_scale": guidance_scale,
            "average_samples": average_samples,
            "mirror_average": mirror_average,
            "compat": compat,
            "object_fraction": object_fraction,
            "source": source,
        }
        return replace(self, **{k: v for k, v in given.items() if v is not None})

    def sampling_config(
        self, *, latent_mode: LatentModeName | None = None, **fields: Any
    ) -> SamplingConfig:
        """This setting as a `SamplingConfig`; `latent_mode` None: the one `compat` brings.

        Args:
            latent_mode: overrides the rule of `latent_mode_for`.
            fields: other `SamplingConfig` fields (scheduler, eta, nonfinite, ...).
        """
        return SamplingConfig(
            num_inference_steps=self.num_inference_steps,
            guidance_scale=float(self.guidance_scale),
            average_samples=self.average_samples,
            mirror_average=bool(self.mirror_average),
            latent_mode=latent_mode or self.latent_mode,
            **fields,
        )


SuggestedSampling = DefaultSampling
"""The former name of `DefaultSampling` (kept for code written against gaffer-diffusion 0.x)."""

PAPER_SAMPLING = DefaultSampling(
    num_inference_steps=50,
    guidance_scale=3.0,
    compat="neural-gaffer",
    source="the paper's settings (the model folder records none)",
)
"""The paper's sampling, for the authors' checkpoint and for model folders that record none."""

PAPER_SUGGESTION = PAPER_SAMPLING
"""The former name of `PAPER_SAMPLING`."""


def read_default_sampling(folder: Path) -> DefaultSampling:
    """The setting recorded in `folder/gaffer_model.json`, or `PAPER_SAMPLING` when none is.

    A folder without our manifest (the authors' `checkpoint-80000/`) gets the paper's setting
    (the shipped gaffer-tiny's: `pretrained.gaffer_tiny_sampling()`).

    Raises:
        CheckpointMismatchError: the manifest is unreadable or its block is malformed (named).
    """
    path = Path(folder) / MANIFEST_NAME
    if not path.is_file():
        return PAPER_SAMPLING
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointMismatchError(f"{path} is not readable JSON ({exc}).") from exc
    block = manifest.get(SUGGESTION_KEY) if isinstance(manifest, dict) else None
    if block is None:
        return PAPER_SAMPLING
    if not isinstance(block, dict):
        raise CheckpointMismatchError(f"{path}: `{SUGGESTION_KEY}` is not an object.")
    known = set(DefaultSampling.__dataclass_fields__) - {"source"}
    unknown = sorted(set(block) - known)
    if unknown:
        raise CheckpointMismatchError(
            f"{path}: `{SUGGESTION_KEY}` has unknown keys {unknown}; upgrade gaffer-diffusion."
        )
    try:
        return DefaultSampling(**block, source=f"the model's own ({path})")
    except (TypeError, ValueError) as exc:
        raise CheckpointMismatchError(f"{path}: `{SUGGESTION_KEY}` is malformed: {exc}.") from exc


read_suggested_sampling = read_default_sampling
"""The former name of `read_default_sampling`."""


def suggestion_from_training_config(config: dict[str, Any]) -> DefaultSampling:
    """What a trained model suggests, from its training config (`train_state.json`'s `config`).

    The encoding and framing it was trained with, the sampler it was validated with, and the mirror
    mean when it was trained with mirror augmentation (relighting commutes with the mirror, so the
    mean of both is a better estimate).
    """
    data = config.get("data", {}) if isinstance(config, dict) else {}
    val = config.get("validation", {}) if isinstance(config, dict) else {}
    return DefaultSampling(
        num_inference_steps=int(val.get("num_inference_steps", 50)),
        guidance_scale=float(val.get("guidance_scale", 3.0)),
        mirror_average=float(data.get("mirror_prob", 0.0)) > 0.0,
        compat=data.get("lighting_compat", "default"),
        object_fraction=data.get("object_fraction"),
        source="its training config",
    )
