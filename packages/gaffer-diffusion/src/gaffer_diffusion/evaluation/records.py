"""The records of an evaluation: which pairs, how to run it, what it found."""

from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from gaffer_diffusion._json import json_dumps
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.metrics import MetricsReport, closer_than
from gaffer_diffusion.pipelines import SamplingConfig
from gaffer_diffusion.suggested import DefaultSampling
from gaffer_envmap.compat_mode import CompatArg

InputLighting = int | Literal["area"]
"""Which render of a view is the model's input: a lighting index `LLL`, or "area" (area-light render)."""

ENVMAP_SUFFIXES = (".exr", ".hdr")


@dataclass(frozen=True, kw_only=True)
class EnvmapLighting:
    """A target lighting as the renderer used it: a world map, its augmentation and the camera.

    Attributes:
        source: the environment-map file (lat-long, Blender convention, z up).
        flip: mirrored horizontally before the yaw (gaffer-envmap `AugmentSpec`).
        yaw_step: roll by `yaw_step / num_steps` of a turn.
        num_steps: yaw steps per turn.
        strength: Blender world strength the radiance was multiplied by.
        w2c_blender: `[3, 4]` world-to-camera matrix of the view (Blender camera axes).
    """

    source: Path
    flip: bool
    yaw_step: int
    num_steps: int
    strength: float
    w2c_blender: np.ndarray = field(repr=False, compare=False)


@dataclass(frozen=True, kw_only=True)
class EncodedLightingFiles:
    """A target lighting given as already-encoded camera-frame maps (the authors' release).

    Attributes:
        ldr: PNG of the LDR map E_L (8-bit, 256x256 in the release).
        hdr: PNG of the log-normalised HDR map E_H.
    """

    ldr: Path
    hdr: Path


DatasetKind = Literal["render", "authors"]
"""A gaffer-data render (`gaffer.render_dataset`) or a converted authors' layout
(`gaffer.authors_dataset`); the same Literal as `gaffer_data.dataset.DatasetKind`, repeated here so
that importing this module does not need gaffer-data."""


@dataclass(frozen=True, kw_only=True)
class EvalPair:
    """One (input render, target lighting) pair of the same object and view.

    Attributes:
        name: `"{object_id}/{VVV}_{input}_to_{LLL}"`, unique in a dataset.
        object_id: the object.
        view_index: the camera view `VVV`.
        target_lighting: the target lighting index `LLL`.
        input_image: RGBA PNG of the input render (sRGB, straight alpha).
        target_image: RGBA PNG of the ground-truth render under the target lighting.
        mask: the view's 8-bit object mask, or None (the target's alpha channel is used).
        lighting: the target lighting: an env map to encode, or the authors' encoded maps.
    """

    name: str
    object_id: str
    view_index: int
    target_lighting: int
    input_image: Path
    target_image: Path
    mask: Path | None
    lighting: EnvmapLighting | EncodedLightingFiles


@dataclass(frozen=True, kw_only=True)
class EvaluationConfig:
    """How `evaluate_dataset` samples and scores.

    Attributes:
        sampling: steps, guidance and sampler (default: the paper's DDIM 50, CFG 3).
        seed: seed of every pair's initial noise (the same for each pair, so results do not depend on
            batching or order).
        batch_size: pairs per sampling call.
        compat: gaffer-envmap lighting encoding; "neural-gaffer" matches the released checkpoint.
        predictions_dir: also write every prediction as `DIR/{name}.png`; None: keep nothing.
        progress: show a tqdm progress bar on stderr.
        baselines: also score the unrelit input against each target (its "aligned" rows are the
            second baseline, the input channel-aligned to the target); a relighting model is only
            useful where it beats both.
        keep_background: keep the input outside its alpha mask (`RelightingConditions.mask`): the
            view is fixed, so the background is known. False scores the model's full frame as the
            authors' code does.
        object_fraction: None: every render is read whole (the authors' protocol). A fraction f:
            each view is cropped to the square centred on its object with the object's longer
            side spanning f of it (`gaffer_diffusion.preprocess.object_square`), input and target
            alike, as a model trained with `DataConfig.object_fraction` saw its data.

    Raises:
        ConfigError: on a non-positive `batch_size`, an unknown `compat` or an `object_fraction`
            outside (0, 1].
    """

    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    seed: int = 0
    batch_size: int = 4
    compat: CompatArg = "neural-gaffer"
    predictions_dir: Path | None = None
    progress: bool = False
    baselines: bool = True
    keep_background: bool = True
    object_fraction: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ConfigError(f"`batch_size` is {self.batch_size!r}; expected an int >= 1.")
        if self.compat not in ("neural-gaffer", "default"):
            raise ConfigError(
                f"`compat` is {self.compat!r}; expected 'neural-gaffer' (released checkpoint) or "
                "'default'."
            )
        if self.object_fraction is not None and not 0.0 < self.object_fraction <= 1.0:
            raise ConfigError(
                f"`object_fraction` is {self.object_fraction}; expected a fraction in (0, 1], "
                "or None for the whole render."
            )


@dataclass(frozen=True, kw_only=True)
class DatasetEvaluation:
    """Result of `evaluate_dataset`: the scores and everything needed to reproduce them.

    Attributes:
        report: per-pair and mean metrics (raw, aligned over the image, aligned over the mask).
        settings: dataset, checkpoint, sampling, seed, dtype, device, ... as plain JSON values.
        seconds: wall time of sampling and scoring.
        baseline: the same metrics for the unrelit input image (raw: the identity baseline; aligned:
            the input channel-aligned to the target); None when `EvaluationConfig.baselines` is off.
    """

    report: MetricsReport
    settings: dict[str, Any]
    seconds: float
    baseline: MetricsReport | None = None

    @property
    def closer_than_input(self) -> float | None:
        """Share of pairs whose object-mask PSNR beats the unrelit input's (None without both)."""
        if self.baseline is None:
            return None
        return closer_than(self.report, self.baseline)

    def summary(self) -> str:
        """One paragraph leading with the object-mask scores beside the unrelit input's."""
        r, b = self.report, self.baseline
        if r.mean_object_raw is None or r.mean_object_aligned is None:
            return f"full frame PSNR {r.mean_raw.psnr:.2f} dB ({len(r.items)} pairs)"
        text = (
            f"object mask: PSNR {r.mean_object_raw.psnr:.2f} dB raw, "
            f"{r.mean_object_aligned.psnr:.2f} dB aligned"
        )
        if b is not None and b.mean_object_raw is not None and b.mean_object_aligned is not None:
            text += (
                f" (unrelit input {b.mean_object_raw.psnr:.2f} / {b.mean_object_aligned.psnr:.2f} dB);"
                f" closer than the input on {100 * (self.closer_than_input or 0):.0f}% of pairs"
            )
        text += f"; full frame PSNR {r.mean_raw.psnr:.2f} dB"
        if b is not None:
            text += f" (input {b.mean_raw.psnr:.2f} dB)"
        return text + f"; {len(r.items)} pairs"

    def to_json(self) -> str:
        """Settings, timing and the full report as one strict JSON document: an infinite PSNR is
        null, with its JSON Pointer under `"non_finite"` (`gaffer_diffusion._json`)."""
        return json_dumps(
            {
                "settings": self.settings,
                "summary": self.summary(),
                "closer_than_input": self.closer_than_input,
                "seconds": round(self.seconds, 3),
                "metrics": asdict(self.report),
                "baseline_unrelit_input": None if self.baseline is None else asdict(self.baseline),
            },
            indent=2,
        )

    def to_markdown(self) -> str:
        """The settings as a list, then the table of means (and the baseline's, when scored)."""
        lines = ["| setting | value |", "|---|---|"]
        lines += [f"| {k} | {v} |" for k, v in self.settings.items()]
        text = "\n".join(lines) + f"\n\n**{self.summary()}**"
        text += "\n\nRelit by the model:\n\n" + self.report.to_markdown()
        if self.baseline is not None:
            text += (
                "\n\nBaseline, the unrelit input (its aligned rows: the input channel-aligned to "
                "the target):\n\n" + self.baseline.to_markdown()
            )
        return text


def suggested_evaluation_config(
    suggested: DefaultSampling, *, seed: int = 0, batch_size: int = 8
) -> EvaluationConfig:
    """The evaluation a model's own sampling asks for (`RelightPipeline.default_sampling`): its
    steps, guidance, averaging, lighting encoding (and the latent mode it brings) and framing, the
    input's background kept, as `gaffer-diffusion evaluate` scores a model when no sampling flag
    overrides it."""
    fraction = suggested.object_fraction
    return EvaluationConfig(
        sampling=suggested.sampling_config(),
        seed=seed,
        batch_size=batch_size,
        compat=suggested.compat,
        keep_background=True,
        object_fraction=None if fraction is None else float(fraction),
    )
