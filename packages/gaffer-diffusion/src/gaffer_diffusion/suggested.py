"""A model's own suggested sampling, stored in its folder's manifest (`gaffer_model.json`).

A model is only right when it is sampled the way it was trained and evaluated: gaffer-tiny with one
DDIM step and gaffer-envmap's "default" lighting encoding, the authors' checkpoint with 50 steps,
guidance 3 and their "neural-gaffer" encoding (official implementation §2). A self-trained model relit
with another model's encoding silently relights wrong, so the setting travels with the weights:
`gaffer-diffusion export` writes it from the training config (the encoding and framing trained with,
the sampler validated with), and every path that samples a model (`relight`, `evaluate`, `demo`,
gaffer-nerf's stages) reads it with `read_suggested_sampling` unless the user overrides a value.

Reading it is a JSON read (no torch), so commands can check arguments against it before loading weights.
"""

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import CheckpointMismatchError

__all__ = [
    "PAPER_SUGGESTION",
    "SUGGESTION_KEY",
    "SuggestedSampling",
    "read_suggested_sampling",
    "suggestion_from_training_config",
]

SUGGESTION_KEY = "suggested_sampling"
"""The manifest key holding a `SuggestedSampling`."""


if TYPE_CHECKING:
    _CompatArg = Literal["neural-gaffer", "default"]
else:  # from a manifest any value reaches `compat`; `__post_init__` names a wrong one (ValueError)
    _CompatArg = object


@dataclass(frozen=True, kw_only=True)
class SuggestedSampling:
    """How a model is meant to be sampled.

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
        problems = []
        if not (
            isinstance(self.num_inference_steps, int) and 1 <= self.num_inference_steps <= 1000
        ):
            problems.append(f"num_inference_steps {self.num_inference_steps!r} (need 1..1000)")
        g = self.guidance_scale
        if not (isinstance(g, int | float) and math.isfinite(g) and g >= 0):
            problems.append(f"guidance_scale {g!r} (need finite >= 0)")
        if not (isinstance(self.average_samples, int) and self.average_samples >= 1):
            problems.append(f"average_samples {self.average_samples!r} (need >= 1)")
        if self.compat not in ("neural-gaffer", "default"):
            problems.append(f"compat {self.compat!r} (need 'neural-gaffer' or 'default')")
        f = self.object_fraction
        if f is not None and not (isinstance(f, int | float) and 0 < f <= 1):
            problems.append(f"object_fraction {f!r} (need (0, 1] or null)")
        if problems:
            raise ValueError("suggested sampling: " + "; ".join(problems))

    def to_json(self) -> dict[str, Any]:
        """The manifest block (without `source`, which says where a reader found it)."""
        body = asdict(self)
        body.pop("source")
        return body


PAPER_SUGGESTION = SuggestedSampling(
    num_inference_steps=50,
    guidance_scale=3.0,
    compat="neural-gaffer",
    source="the paper's settings (the model folder records none)",
)
"""The paper's sampling, for the authors' checkpoint and for model folders that record none."""


def read_suggested_sampling(folder: Path) -> SuggestedSampling:
    """The suggestion recorded in `folder/gaffer_model.json`, or `PAPER_SUGGESTION` when none is.

    A folder without our manifest (the authors' `checkpoint-80000/`) gets the paper's setting.

    Raises:
        CheckpointMismatchError: the manifest is unreadable or its block is malformed (named).
    """
    path = Path(folder) / MANIFEST_NAME
    if not path.is_file():
        return PAPER_SUGGESTION
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointMismatchError(f"{path} is not readable JSON ({exc}).") from exc
    block = manifest.get(SUGGESTION_KEY) if isinstance(manifest, dict) else None
    if block is None:
        return PAPER_SUGGESTION
    if not isinstance(block, dict):
        raise CheckpointMismatchError(f"{path}: `{SUGGESTION_KEY}` is not an object.")
    known = set(SuggestedSampling.__dataclass_fields__) - {"source"}
    unknown = sorted(set(block) - known)
    if unknown:
        raise CheckpointMismatchError(
            f"{path}: `{SUGGESTION_KEY}` has unknown keys {unknown}; upgrade gaffer-diffusion."
        )
    try:
        return SuggestedSampling(**block, source=f"the model's own ({path})")
    except (TypeError, ValueError) as exc:
        raise CheckpointMismatchError(f"{path}: `{SUGGESTION_KEY}` is malformed: {exc}.") from exc


def suggestion_from_training_config(config: dict[str, Any]) -> SuggestedSampling:
    """What a trained model suggests, from its training config (`train_state.json`'s `config`).

    The encoding and framing it was trained with, the sampler it was validated with, and the mirror
    mean when it was trained with mirror augmentation (relighting commutes with the mirror, so the
    mean of both is a better estimate).
    """
    data = config.get("data", {}) if isinstance(config, dict) else {}
    val = config.get("validation", {}) if isinstance(config, dict) else {}
    return SuggestedSampling(
        num_inference_steps=int(val.get("num_inference_steps", 50)),
        guidance_scale=float(val.get("guidance_scale", 3.0)),
        mirror_average=float(data.get("mirror_prob", 0.0)) > 0.0,
        compat=data.get("lighting_compat", "default"),
        object_fraction=data.get("object_fraction"),
        source="its training config",
    )
