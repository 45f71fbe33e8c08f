"""Evaluate a relighting model on a rendered dataset (paper §4, official implementation §5).

A gaffer-data dataset holds, per object and camera view, renders under several environment-map draws
(`lit/{VVV}_{LLL}.png`), the camera pose and which map (and augmentation) lit each render. Evaluation
pairs one render of a view (the *input*, lighting `input_lighting`, or the area-light render) with every
other lighting of the same view (the *targets*), as the paper's protocol does (input and target share
the camera; only the lighting changes). For each pair the model relights the input under the target's
environment map, rotated into the view's camera frame by gaffer-envmap (`compat="neural-gaffer"` by
default, the encoding of the released checkpoint), and the prediction is scored against the target
render with `gaffer_diffusion.metrics`: PSNR, SSIM and the perceptual distance, raw and channel-aligned
(means over the whole image and over the object mask), per pair and averaged.

Datasets converted from the authors' released validation layout (`gaffer-data convert-authors`, schema
"gaffer.authors_dataset") are read too: there the target lighting comes as the authors' pre-encoded
camera-frame LDR/HDR maps (`envmap_ldr/`, `envmap_hdr/`), used as they are (no env map, no `compat`).

Images are scored the way the authors score them: full frame, object composited on a white background,
prediction quantised to 8 bits. Renders at another resolution than the model's are resized (PIL bicubic)
before use, for input and target alike.

gaffer-data is imported lazily, only here: `pip install "gaffer-diffusion[eval]"`.
"""

import functools
import logging
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, NoReturn

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from gaffer_diffusion._json import json_dumps
from gaffer_diffusion.conditioning import (
    CompatMode,
    LightingMaps,
    RelightingConditions,
    lighting_from_envmap,
)
from gaffer_diffusion.errors import ConfigError, DatasetError, MissingDependencyError
from gaffer_diffusion.metrics import (
    MetricsReport,
    PerceptualMetric,
    closer_than,
    combine_reports,
    evaluate_images,
    load_perceptual,
)
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
from gaffer_diffusion.preprocess import (
    crop_square,
    load_rgba_on_white,
    object_square,
    read_alpha,
)
from gaffer_envmap.compat_mode import CompatArg

logger = logging.getLogger(__name__)

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


def _require_gaffer_data() -> Any:
    try:
        import gaffer_data
    except ImportError as exc:
        raise MissingDependencyError(
            'Evaluating on a rendered dataset needs gaffer-data: pip install "gaffer-diffusion[eval]"'
        ) from exc
    return gaffer_data


def _resolve_envmap(
    source: str, name: str, dataset_root: Path, envmap_dirs: Sequence[Path]
) -> Path:
    """Find an env map that may have moved since rendering: as recorded, then by name in the dirs."""
    recorded = Path(source)
    candidates = [recorded]
    if not recorded.is_absolute():
        candidates.append(dataset_root / recorded)
    for d in envmap_dirs:
        candidates.append(Path(d) / recorded.name)
        candidates += [Path(d) / f"{name}{suffix}" for suffix in ENVMAP_SUFFIXES]
    for c in candidates:
        if c.is_file():
            return c
    looked = "\n".join(f"  - {c}" for c in candidates)
    raise DatasetError(
        f"The environment map `{name}` that lit this dataset was not found. Looked in:\n{looked}\n"
        "Pass the folder holding the maps the dataset was rendered with as `--envmaps DIR` "
        "(`envmap_dirs`)."
    )


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _verified_envmap(path: Path, name: str, expected: str, moved: bool) -> Path:
    """`path`, once its sha256 matches the `source_sha256` its manifest recorded (issue 17): a map of
    the right name but other content would score every pair against the wrong lighting."""
    if not expected:
        return path  # an older manifest without the digest: nothing to check against
    actual = _sha256(path)
    if actual != expected.lower():
        fix = (
            "pass `--envmaps DIR` with the maps the dataset was rendered with"
            if moved
            else "restore the original map, or pass `--envmaps DIR` with the maps it was rendered with"
        )
        raise DatasetError(
            f"Environment map `{path}` is not the `{name}` this dataset was rendered with: its "
            f"sha256 is {actual[:12]}..., the manifest records {expected[:12]}...; {fix}."
        )
    return path


def dataset_pairs(
    root: str | Path,
    *,
    input_lighting: InputLighting = 0,
    envmap_dirs: Sequence[str | Path] = (),
    limit: int | None = None,
) -> tuple[EvalPair, ...]:
    """Every (input, target lighting) pair of a gaffer-data dataset (rendered or converted).

    Args:
        root: the dataset folder: a render (`gaffer_data.open_dataset`) or a converted authors' split
            (`gaffer_data.open_authors_dataset`); the kind is read from its `dataset.json`.
        input_lighting: the lighting index of the input render of each view, or "area" for the
            area-light render (then every lighting is a target).
        envmap_dirs: folders to search for env maps whose recorded path no longer exists (renders
            only; converted datasets carry encoded maps).
        limit: keep only the first `limit` pairs (in object, view, lighting order).

    Returns:
        The pairs, in object, view, target-lighting order.

    Raises:
        MissingDependencyError: without gaffer-data.
        DatasetError: when the dataset yields no pair, a view lacks the input render, or an env map
            cannot be found.
    """
    gaffer_data = _require_gaffer_data()
    if limit is not None and limit < 1:
        raise ConfigError(f"`limit` is {limit}; expected >= 1 or None.")
    if not (input_lighting == "area" or (isinstance(input_lighting, int) and input_lighting >= 0)):
        raise ConfigError(
            f"`input_lighting` is {input_lighting!r}; expected a lighting index >= 0 or 'area'."
        )
    root = Path(root)
    if dataset_kind(root) == "authors":
        pairs = _authors_pairs(gaffer_data, root, input_lighting, limit)
    else:
        pairs = _render_pairs(gaffer_data, root, input_lighting, envmap_dirs, limit)
    if not pairs:
        raise DatasetError(
            f"`{root}` yields no (input, target) pair: it needs complete objects (with manifest.json) "
            "and at least two lightings per view (or `input_lighting='area'`)."
        )
    return tuple(pairs)


def dataset_kind(root: str | Path) -> DatasetKind:
    """ "authors" when `root/dataset.json` declares a converted authors' layout, else "render".

    Re-exported for compatibility: the test belongs to gaffer-data's format and lives in
    `gaffer_data.dataset.dataset_kind` (gaffer-data is imported here, not at module import).
    """
    from gaffer_data.dataset import dataset_kind as _kind

    return _kind(root)


def _missing_input(
    object_id: str, view: int, input_lighting: InputLighting, have: object
) -> NoReturn:
    if input_lighting == "area":
        raise DatasetError(
            f"`{object_id}` view {view} has no area-light render; pass a lighting index as "
            "`input_lighting` (`--input-lighting 0`)."
        )
    raise DatasetError(
        f"`{object_id}` view {view} has no lighting {input_lighting} (it has {have}); choose "
        "another `input_lighting`."
    )


def _authors_pairs(
    gaffer_data: Any, root: Path, input_lighting: InputLighting, limit: int | None
) -> list[EvalPair]:
    pairs: list[EvalPair] = []
    for obj in gaffer_data.open_authors_dataset(root).iter_objects():
        for view in obj.views:
            by_index = {lit.lighting_index: lit for lit in view.lit}
            if input_lighting == "area":
                if view.area_png is None:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = obj.path(view.area_png), "area"
            else:
                if input_lighting not in by_index:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = (
                    obj.path(by_index[input_lighting].png),
                    f"{input_lighting:03d}",
                )
            for lit in view.lit:
                if lit.lighting_index == input_lighting:
                    continue
                pairs.append(
                    EvalPair(
                        name=f"{obj.object_id}/{view.index:03d}_{input_tag}_to_{lit.lighting_index:03d}",
                        object_id=obj.object_id,
                        view_index=view.index,
                        target_lighting=lit.lighting_index,
                        input_image=input_png,
                        target_image=obj.path(lit.png),
                        mask=None,
                        lighting=EncodedLightingFiles(
                            ldr=obj.path(lit.envmap_ldr), hdr=obj.path(lit.envmap_hdr)
                        ),
                    )
                )
                if limit is not None and len(pairs) >= limit:
                    return pairs
    return pairs


def _render_pairs(
    gaffer_data: Any,
    root: Path,
    input_lighting: InputLighting,
    envmap_dirs: Sequence[str | Path],
    limit: int | None,
) -> list[EvalPair]:
    dirs = tuple(Path(d) for d in envmap_dirs)
    resolve = functools.lru_cache(maxsize=None)(
        lambda source, name, sha: _verified_envmap(
            _resolve_envmap(source, name, root, dirs), name, sha, bool(dirs)
        )
    )
    pairs: list[EvalPair] = []
    skipped_same = 0
    for obj in gaffer_data.open_dataset(root).iter_objects():
        poses = obj.poses()
        for view in obj.views:
            by_index = {lit.lighting_index: lit for lit in view.lit}
            if input_lighting == "area":
                if view.area is None:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = obj.path(view.area.png), "area"
            else:
                if input_lighting not in by_index:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png = obj.path(by_index[input_lighting].png)
                input_tag = f"{input_lighting:03d}"
            same = None if input_lighting == "area" else _lighting_key(by_index[input_lighting])
            for lit in view.lit:
                if lit.lighting_index == input_lighting:
                    continue
                if _lighting_key(lit) == same:
                    # the same map, mirror, turn and strength as the input: the render is the input
                    # itself (a duplicate draw), not a relighting task, and its PSNR is infinite
                    skipped_same += 1
                    continue
                ref = lit.envmap
                pairs.append(
                    EvalPair(
                        name=f"{obj.object_id}/{view.index:03d}_{input_tag}_to_{lit.lighting_index:03d}",
                        object_id=obj.object_id,
                        view_index=view.index,
                        target_lighting=lit.lighting_index,
                        input_image=input_png,
                        target_image=obj.path(lit.png),
                        mask=None if view.alpha is None else obj.path(view.alpha),
                        lighting=EnvmapLighting(
                            source=resolve(ref.source, ref.name, ref.source_sha256),
                            flip=bool(ref.flip),
                            yaw_step=int(ref.yaw_step),
                            num_steps=int(ref.num_steps),
                            strength=float(ref.strength),
                            w2c_blender=np.asarray(poses.w2c_blender[view.index], np.float64),
                        ),
                    )
                )
                if limit is not None and len(pairs) >= limit:
                    return _log_skipped(pairs, skipped_same)
    return _log_skipped(pairs, skipped_same)


def _lighting_key(lit: Any) -> tuple[object, ...]:
    """What decides a render's lighting: the map (by content hash), mirror, turn and strength."""
    ref = lit.envmap
    return (ref.source_sha256 or ref.name, bool(ref.flip), int(ref.yaw_step), float(ref.strength))


def _log_skipped(pairs: list[EvalPair], skipped: int) -> list[EvalPair]:
    if skipped:
        logger.info(
            "left out %d target(s) lit exactly as their input (same map, mirror, turn and strength)",
            skipped,
        )
    return pairs


def read_rgba_on_white(
    path: Path, size: int, box: tuple[int, int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """`[S, S, 3]` float32 sRGB composited on white and `[S, S]` alpha, both in [0, 1], read by the
    same loader as training (`gaffer_diffusion.preprocess.load_rgba_on_white`), optionally cropped."""
    try:
        rgb, alpha = load_rgba_on_white(path, size, None, box)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the render `{path}`: {exc}. Re-render it.") from exc
    return rgb.permute(1, 2, 0).numpy(), alpha[0].numpy()


def pair_crop_box(pair: "EvalPair", object_fraction: float | None) -> tuple[int, int, int] | None:
    """The object-centred square of `pair`'s view (from its mask, else the input's alpha), or None."""
    if object_fraction is None:
        return None
    src = pair.mask if pair.mask is not None else pair.input_image
    try:
        return object_square(read_alpha(src), object_fraction)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the mask `{src}`: {exc}. Re-render it.") from exc


def read_mask(path: Path, size: int, box: tuple[int, int, int] | None = None) -> np.ndarray:
    """`[S, S]` float32 mask in [0, 1] from a greyscale (or any) image file, optionally cropped to
    `box`, resized to `size` (bilinear, antialiased, as the images)."""
    try:
        with Image.open(path) as im:
            m = np.asarray(im.convert("L"), np.float32)[..., None] / 255.0
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the mask `{path}`: {exc}. Re-render it.") from exc
    if box is not None:
        m = crop_square(m, box, 0.0)
    t = torch.from_numpy(np.ascontiguousarray(m)).permute(2, 0, 1)[None]
    if tuple(t.shape[2:]) != (size, size):
        t = F.interpolate(
            t, size=(size, size), mode="bilinear", align_corners=False, antialias=True
        )
    return t[0, 0].clamp(0, 1).numpy()


@functools.lru_cache(maxsize=8)
def _augmented_envmap(
    source: Path, flip: bool, yaw_step: int, num_steps: int, strength: float
) -> Any:
    from gaffer_envmap import AugmentSpec, EnvironmentMap
    from gaffer_envmap.io import read_envmap

    env = AugmentSpec(flip=flip, yaw_step=yaw_step, num_steps=num_steps).apply(
        read_envmap(source, sanitize="zero")
    )
    if strength != 1.0:
        env = EnvironmentMap(radiance_linear=np.asarray(env.radiance_linear) * np.float32(strength))
    return env


def read_lighting_map(path: Path, size: int) -> Tensor:
    """`[1, 3, size, size]` encoded lighting map in [0, 1] (PIL bilinear when resized, as the authors)."""
    try:
        with Image.open(path) as im:
            rgb = im.convert("RGB")
            if rgb.size != (size, size):
                rgb = rgb.resize((size, size), Image.Resampling.BILINEAR)
            arr = np.asarray(rgb, np.float32) / 255.0
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the lighting map `{path}`: {exc}.") from exc
    return torch.from_numpy(arr).permute(2, 0, 1)[None].contiguous()


def pair_lighting(pairs: Sequence[EvalPair], size: int, compat: CompatMode) -> LightingMaps:
    """Camera-frame LDR/HDR maps of each pair's target lighting, `[B, 3, size, size]`.

    Env maps are augmented, rotated into the view's camera frame and encoded with `compat`; the
    authors' pre-encoded maps are read as they are (resized if the model resolution differs).

    Raises:
        DatasetError: when a map cannot be read or augmented.
    """
    ldr, hdr = [], []
    for p in pairs:
        lt = p.lighting
        if isinstance(lt, EncodedLightingFiles):
            ldr.append(read_lighting_map(lt.ldr, size))
            hdr.append(read_lighting_map(lt.hdr, size))
            continue
        try:
            env = _augmented_envmap(lt.source, lt.flip, lt.yaw_step, lt.num_steps, lt.strength)
        except (OSError, ValueError) as exc:
            raise DatasetError(
                f"Could not read or augment the environment map `{lt.source}` of `{p.name}`: {exc}"
            ) from exc
        w2c = torch.tensor(lt.w2c_blender[None])  # [1, 3, 4], a copy (the pose is read-only)
        maps = lighting_from_envmap(env, w2c, size=size, compat=compat)
        ldr.append(maps.ldr)
        hdr.append(maps.hdr)
    return LightingMaps(ldr=torch.cat(ldr), hdr=torch.cat(hdr))


def _to_chw(arrs: list[np.ndarray]) -> Tensor:
    t = torch.from_numpy(np.stack(arrs))
    return t.permute(0, 3, 1, 2).contiguous() if t.ndim == 4 else t[:, None].contiguous()


def quantize_8bit(images: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 3 H W"]:
    """Round to the 8-bit grid, as writing and re-reading a PNG would (the authors score PNGs).

    Example:
        >>> import torch
        >>> x = quantize_8bit(torch.full((1, 3, 1, 1), 0.301))
        >>> round(float(x[0, 0, 0, 0]) * 255, 3)
        77.0
    """
    return (images.clamp(0.0, 1.0) * 255.0).round() / 255.0


def _batches(pairs: Sequence[EvalPair], size: int) -> Iterator[Sequence[EvalPair]]:
    for lo in range(0, len(pairs), size):
        yield pairs[lo : lo + size]


def evaluate_dataset(
    pipe: RelightPipeline,
    pairs: Sequence[EvalPair],
    config: EvaluationConfig | None = None,
    *,
    perceptual: PerceptualMetric | Literal["auto"] | None = "auto",
    settings: dict[str, Any] | None = None,
    on_batch: Callable[[int, int], None] | None = None,
) -> DatasetEvaluation:
    """Relight every pair and score it against its ground truth.

    Args:
        pipe: the relighting pipeline (its model's resolution is the working resolution).
        pairs: from `dataset_pairs`.
        config: sampling, seed, batch size, lighting encoding, prediction folder, progress bar.
        perceptual: a loaded metric, None to skip it, or "auto" (shift-tolerant LPIPS when it loads,
            otherwise the report says why not).
        settings: extra entries for the report's settings (e.g. the checkpoint path).
        on_batch: called as `on_batch(pairs_done, pairs_total)` after every batch.

    Returns:
        A `DatasetEvaluation`; its settings record the sampling, seed, dtype, device and pair count.

    Raises:
        DatasetError: on an empty `pairs` or an unreadable file.
        NonFiniteOutputError: when sampling yields NaN/Inf (see `SamplingConfig.nonfinite`).
    """
    config = config or EvaluationConfig()
    if not pairs:
        raise DatasetError("`pairs` is empty; build them with `dataset_pairs(root)`.")
    size = pipe.model.config.resolution
    reason = None
    if perceptual == "auto":
        from gaffer_diffusion.errors import MetricUnavailableError

        try:
            perceptual = load_perceptual()
        except MetricUnavailableError as exc:
            perceptual, reason = None, str(exc)
    bar = None
    if config.progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(pairs), desc="evaluate", unit="pair")
    start = time.perf_counter()
    reports: list[MetricsReport] = []
    baselines: list[MetricsReport] = []
    done = 0
    try:
        for batch in _batches(pairs, config.batch_size):
            boxes = [pair_crop_box(p, config.object_fraction) for p in batch]
            inputs, input_alphas = zip(
                *(read_rgba_on_white(p.input_image, size, bx) for p, bx in zip(batch, boxes)),
                strict=True,
            )
            targets, alphas = zip(
                *(read_rgba_on_white(p.target_image, size, bx) for p, bx in zip(batch, boxes)),
                strict=True,
            )
            masks = [
                a if p.mask is None else read_mask(p.mask, size, bx)
                for p, a, bx in zip(batch, alphas, boxes, strict=True)
            ]
            cond = RelightingConditions(
                image=_to_chw(list(inputs)),
                lighting=pair_lighting(batch, size, config.compat),
                mask=_to_chw(list(input_alphas)) if config.keep_background else None,
            )
            out = pipe(cond, config.sampling, seeds=[config.seed] * len(batch))
            pred = quantize_8bit(out.images.float().cpu())
            if config.predictions_dir is not None:
                _save_predictions(config.predictions_dir, batch, pred)
            report = evaluate_images(
                pred,
                _to_chw(list(targets)),
                mask=_to_chw(masks),
                names=[p.name for p in batch],
                perceptual=perceptual,
            )
            if config.baselines:
                baselines.append(
                    evaluate_images(
                        _to_chw(list(inputs)),
                        _to_chw(list(targets)),
                        mask=_to_chw(masks),
                        names=[p.name for p in batch],
                        perceptual=perceptual,
                    )
                )
            if reason is not None:
                report = _with_reason(report, reason)
                baselines[-1:] = [_with_reason(b, reason) for b in baselines[-1:]]
            reports.append(report)
            done += len(batch)
            if bar is not None:
                bar.update(len(batch))
            if on_batch is not None:
                on_batch(done, len(pairs))
    finally:
        if bar is not None:
            bar.close()
    seconds = time.perf_counter() - start
    s = config.sampling
    info: dict[str, Any] = {
        **(settings or {}),
        "pairs": len(pairs),
        "objects": len({p.object_id for p in pairs}),
        "resolution": size,
        "scheduler": s.scheduler,
        "num_inference_steps": s.num_inference_steps,
        "guidance_scale": s.guidance_scale,
        "average_samples": s.average_samples,
        "mirror_average": s.mirror_average,
        "latent_mode": s.latent_mode,
        "seed": config.seed,
        "batch_size": config.batch_size,
        "background": "input kept outside its alpha"
        if config.keep_background
        else "model's full frame",
        "lighting": "authors' pre-encoded maps"
        if isinstance(pairs[0].lighting, EncodedLightingFiles)
        else f"env maps encoded by gaffer-envmap, compat={config.compat!r}",
        "device": pipe.runtime.device,
        "dtype": pipe.runtime.dtype,
        "prediction": "8-bit quantised, on white",
        "framing": "whole render (authors' protocol)"
        if config.object_fraction is None
        else f"object-centred square crop, object spans {config.object_fraction:g} of the side",
        "scores": "object mask first (PSNR of the masked MSE, mask-weighted SSIM, perceptual on "
        "the object's box), then full frame",
        "alignment": "pred_c * mean(gt_c) / mean(pred_c); 'whole image' and 'mask' means",
    }
    return DatasetEvaluation(
        report=combine_reports(reports),
        settings=info,
        seconds=seconds,
        baseline=combine_reports(baselines) if baselines else None,
    )


def _with_reason(report: MetricsReport, reason: str) -> MetricsReport:
    return replace(report, perceptual_unavailable_reason=reason)


def _save_predictions(folder: Path, batch: Sequence[EvalPair], pred: Tensor) -> None:
    for p, img in zip(batch, pred, strict=True):
        path = Path(folder) / f"{p.name}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        arr = (img.permute(1, 2, 0).numpy() * 255.0).round().astype(np.uint8)
        Image.fromarray(arr).save(path)
