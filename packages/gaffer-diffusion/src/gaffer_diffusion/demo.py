"""The end-to-end relighting demo (README's main job): `gaffer-diffusion demo --out DIR`.

Offline and CPU-friendly. It loads gaffer-tiny (the 128 px model shipped inside this package) or a
`--checkpoint`, reads the shipped example object (a gaffer-data render: one view of a held-out object
with ground-truth renders under the bundled CC0 HDRIs), and relights the object's input view

1. under every lighting that has a ground-truth render (scored: PSNR, SSIM and the perceptual metric,
   raw and channel-aligned, beside two baselines: the unrelit input, and the input channel-aligned to
   the target),
2. under every other bundled HDRI (no ground truth: pictures only),
3. under a bundled HDRI spun about world up over `frames` steps (a turntable GIF; by default the
   HDRI whose diffuse light changes most with the spin, `DemoConfig.turntable_hdri`).

All lightings go through the same batched sampling calls with one seed (a result does not depend on
the batch it landed in). It writes, under `out`: the images as PNGs (`inputs/`, `lighting/`, `relit/`,
`ground_truth/`, `turntable/`), `turntable.gif`, `overview.png`, `metrics.json` and a self-contained
`report.html` that links to them by relative path. Every file is written atomically.

Evaluation protocol as in `gaffer_diffusion.evaluation`: full frame, object on white, prediction
quantised to 8 bits; renders at another resolution than the model's are resized (PIL bicubic).
"""

import datetime
import logging
import math
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from gaffer_diffusion import pretrained
from gaffer_diffusion._atomic_dir import atomic_dir
from gaffer_diffusion._json import json_dumps
from gaffer_diffusion._version import __version__
from gaffer_diffusion.conditioning import CompatMode, LightingMaps, RelightingConditions
from gaffer_diffusion.errors import (
    CheckpointNotFoundError,
    ConfigError,
    DatasetError,
    MetricUnavailableError,
    MissingDependencyError,
)
from gaffer_diffusion.evaluation import (
    EnvmapLighting,
    EvalPair,
    InputLighting,
    dataset_pairs,
    quantize_8bit,
)
from gaffer_diffusion.loading import MANIFEST_NAME, load_pretrained
from gaffer_diffusion.metrics import (
    ImageScores,
    MetricsReport,
    closer_than,
    evaluate_images,
    load_perceptual,
)
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig, SamplingConfig
from gaffer_diffusion.report import LightingRow, ReportContent, render_html
from gaffer_envmap.compat_mode import compat_problem

logger = logging.getLogger(__name__)

METRICS_SCHEMA = "gaffer.demo_metrics"
METRICS_SCHEMA_VERSION = "1.0"
DEFAULT_STEPS = 50
"""Denoising steps when neither `num_inference_steps` nor the model suggests a number (paper: 50)."""
DEFAULT_GUIDANCE = 3.0
"""Guidance scale when neither `guidance_scale` nor the model suggests one (paper: 3)."""
GIF_SCALE = 4
"""Nearest-neighbour upscale of the model-size turntable frames in the GIF, so that it is watchable."""

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
        compat: gaffer-envmap lighting encoding; None: the model's own (gaffer-tiny: "default"),
            else "neural-gaffer" (the released checkpoint's).
        object_fraction: crop the example view around its object, which then spans this fraction
            of the side (`gaffer_diffusion.preprocess.object_square`); None: the model's own
            framing (gaffer-tiny: 0.75), else the whole render. 1.0 still crops to the object.
        extra_hdris: also relight under the bundled HDRIs that have no ground-truth render.
        keep_background: keep the input outside its alpha (`RelightingConditions.mask`); False:
            the model's full frame.

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
    compat: CompatMode | None = None
    extra_hdris: bool = True
    keep_background: bool = True
    object_fraction: float | None = None

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
        if self.compat is not None and (problem := compat_problem("compat", self.compat)):
            raise ConfigError(problem)
        if self.object_fraction is not None and not 0.0 < self.object_fraction <= 1.0:
            raise ConfigError(
                f"`object_fraction` is {self.object_fraction!r}; expected a fraction in (0, 1]."
            )


@dataclass(frozen=True, kw_only=True)
class DemoResult:
    """What `run_demo` wrote and how long it took.

    Attributes:
        out: the output folder.
        report_html: `out/report.html`.
        metrics_json: `out/metrics.json`.
        turntable_gif: `out/turntable.gif`, or None with `frames=0`.
        images: number of relit images (scored + extra + turntable frames).
        seconds: wall time of the whole run (model loading included).
        mean_relit: mean scores of the relit images (raw).
        mean_input: mean scores of the unrelit input (raw), the first baseline.
        summary: the headline, object-mask scores first (as in `metrics.json`).
    """

    out: Path
    report_html: Path
    metrics_json: Path
    turntable_gif: Path | None
    images: int
    seconds: float
    mean_relit: ImageScores
    mean_input: ImageScores
    summary: str = ""


@dataclass(frozen=True, kw_only=True)
class LoadedModel:
    """A model and where it came from.

    Attributes:
        model: the networks.
        name: a label for reports ("gaffer-tiny", or the checkpoint's config name).
        source: the folder the weights were read from.
        suggested_steps: the denoising steps the model was evaluated with, if known.
        suggested_guidance: the guidance scale the model was evaluated with, if known.
        suggested_average: the samples averaged per image it was evaluated with, if known.
        suggested_mirror: whether it was evaluated with mirror averaging, if known.
        suggested_compat: the lighting encoding it was trained with, if known.
        suggested_object_fraction: the object framing it was trained with, if known.
    """

    model: NeuralGafferModel
    name: str
    source: Path
    suggested_steps: int | None = None
    suggested_guidance: float | None = None
    suggested_average: int | None = None
    suggested_mirror: bool | None = None
    suggested_compat: CompatMode | None = None
    suggested_object_fraction: float | None = None


def load_model(checkpoint: Path | None, *, flag: str = "--checkpoint") -> LoadedModel:
    """Load `checkpoint` (our format), or gaffer-tiny when it is None (and say so in the log).

    Args:
        checkpoint: a folder written by `save_pretrained` (e.g. `gaffer-diffusion init-random`, or
            training's `final/`); None for the shipped gaffer-tiny.
        flag: the argument's name in error messages.

    Raises:
        CheckpointNotFoundError: `checkpoint` does not exist, or gaffer-tiny's weights are missing
            (the message names the file looked for).
        ConfigError: `checkpoint` is not in our format (the authors' release needs `--base-model`,
            which `gaffer-diffusion relight` and `evaluate` take).
    """
    if checkpoint is None:
        return _load_gaffer_tiny(flag)
    path = Path(checkpoint).expanduser()
    if not path.exists():
        raise CheckpointNotFoundError(
            f"the model folder given as `{flag}`",
            [path],
            f"Pass an existing model folder as `{flag} DIR` (one with {MANIFEST_NAME}, e.g. from "
            f"`gaffer-diffusion init-random --out DIR`), or leave `{flag}` out to use gaffer-tiny.",
        )
    if not (path / MANIFEST_NAME).is_file():
        raise ConfigError(
            f"`{flag}` {path} is not a gaffer-diffusion model folder (no {MANIFEST_NAME}). The demo "
            "reads our format only; relight with the authors' release through `gaffer-diffusion "
            "relight --checkpoint checkpoint-80000/ --base-model DIR`."
        )
    model = load_pretrained(path).model
    from gaffer_diffusion.suggested import PAPER_SUGGESTION, read_suggested_sampling

    own = read_suggested_sampling(path)  # the sampling its folder records (training's, on export)
    if own is PAPER_SUGGESTION:
        return LoadedModel(model=model, name=model.config.name, source=path)
    return LoadedModel(
        model=model,
        name=model.config.name,
        source=path,
        suggested_steps=own.num_inference_steps,
        suggested_guidance=own.guidance_scale,
        suggested_average=own.average_samples,
        suggested_mirror=own.mirror_average,
        suggested_compat=own.compat,
        suggested_object_fraction=own.object_fraction,
    )


def sampling_for(
    loaded: LoadedModel,
    num_inference_steps: int | None,
    guidance_scale: float | None,
    average_samples: int | None = None,
    mirror_average: bool | None = None,
) -> SamplingConfig:
    """DDIM settings: the given values, else the model's suggestion, else the paper's (50, 3).

    Example:
        >>> from gaffer_diffusion.testing import tiny_model
        >>> m = LoadedModel(model=tiny_model(), name="x", source=Path("."), suggested_steps=20)
        >>> s = sampling_for(m, None, None)
        >>> s.num_inference_steps, s.guidance_scale
        (20, 3.0)
    """
    steps = (
        num_inference_steps
        if num_inference_steps is not None
        else loaded.suggested_steps or DEFAULT_STEPS
    )
    if guidance_scale is None:
        guidance_scale = (
            DEFAULT_GUIDANCE if loaded.suggested_guidance is None else loaded.suggested_guidance
        )
    average = average_samples if average_samples is not None else loaded.suggested_average or 1
    if mirror_average is None:
        mirror_average = bool(loaded.suggested_mirror)
    return SamplingConfig(
        num_inference_steps=steps,
        guidance_scale=guidance_scale,
        average_samples=average,
        mirror_average=mirror_average,
    )


def _load_gaffer_tiny(flag: str) -> LoadedModel:
    path = Path(pretrained.gaffer_tiny_path())
    if not (path / MANIFEST_NAME).is_file():
        raise CheckpointNotFoundError(
            "the gaffer-tiny weights",
            [path / MANIFEST_NAME],
            "gaffer-tiny ships inside the gaffer-diffusion package: reinstall it (`pip install "
            f"--force-reinstall gaffer-diffusion`), or pass a model folder as `{flag} DIR`.",
        )
    logger.info("no `%s` given: using gaffer-tiny, the shipped 128 px model (%s)", flag, path)
    return LoadedModel(
        model=pretrained.load_gaffer_tiny().model,
        name="gaffer-tiny",
        source=path,
        suggested_steps=pretrained.GAFFER_TINY_STEPS,
        suggested_guidance=pretrained.GAFFER_TINY_GUIDANCE,
        suggested_average=pretrained.GAFFER_TINY_AVERAGE_SAMPLES,
        suggested_mirror=pretrained.GAFFER_TINY_MIRROR_AVERAGE,
        suggested_compat=pretrained.GAFFER_TINY_COMPAT,  # type: ignore[arg-type]
        suggested_object_fraction=pretrained.GAFFER_TINY_OBJECT_FRACTION,
    )


# --- the example ------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class _Example:
    """One view of the example object: the input and every scored target, at the model resolution."""

    pairs: tuple[EvalPair, ...]
    input_rgb: Tensor  # [1, 3, S, S] on white
    input_alpha: Tensor  # [1, 1, S, S]
    targets: Tensor  # [P, 3, S, S] on white
    masks: Tensor  # [P, 1, S, S]
    w2c_blender: np.ndarray  # [3, 4]


def _require_gaffer_data() -> None:
    try:
        import gaffer_data.dataset  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError(
            "The demo reads its example object with gaffer-data: "
            'pip install "gaffer-diffusion[eval]"'
        ) from exc


def _auto_input(root: Path) -> InputLighting:
    from gaffer_data.dataset import open_dataset

    for obj in open_dataset(root).iter_objects():
        for view in obj.views:
            return "area" if view.area is not None else 0
    raise DatasetError(f"`--example` {root} holds no complete object (objects/*/manifest.json).")


def _read_example(
    root: Path, choice: InputChoice, size: int, object_fraction: float | None = None
) -> _Example:
    from gaffer_diffusion.evaluation import pair_crop_box, read_mask, read_rgba_on_white
    from gaffer_envmap.bundled import bundled_hdris

    _require_gaffer_data()
    from gaffer_data.errors import GafferDataError

    if not (root / "objects").is_dir():
        raise DatasetError(
            f"`--example` {root} is not a gaffer-data render folder (no objects/ in it). Pass a "
            "folder written by `gaffer-data render`, or leave `--example` out for the shipped one."
        )
    hdri_dir = next(iter(bundled_hdris().values())).parent
    try:
        input_lighting = _auto_input(root) if choice == "auto" else choice
        pairs = dataset_pairs(root, input_lighting=input_lighting, envmap_dirs=[hdri_dir])
    except GafferDataError as exc:
        raise DatasetError(f"`--example` {root} cannot be read: {exc}") from exc
    first = pairs[0]
    # one view of one object: the demo relights a single input image
    pairs = tuple(
        p for p in pairs if (p.object_id, p.view_index) == (first.object_id, first.view_index)
    )
    if not isinstance(first.lighting, EnvmapLighting):
        raise DatasetError(
            f"`--example` {root} is a converted authors' dataset (pre-encoded maps, no env maps or "
            "poses): the demo needs a gaffer-data render. Score it with `gaffer-diffusion evaluate`."
        )
    box = pair_crop_box(first, object_fraction)  # one view: one object-centred square
    input_rgb, input_alpha = read_rgba_on_white(first.input_image, size, box)
    targets, masks = [], []
    for p in pairs:
        rgb, alpha = read_rgba_on_white(p.target_image, size, box)
        targets.append(rgb)
        masks.append(alpha if p.mask is None else read_mask(p.mask, size, box))
    return _Example(
        pairs=pairs,
        input_rgb=_chw(np.stack([input_rgb])),
        input_alpha=torch.from_numpy(input_alpha)[None, None].float().contiguous(),
        targets=_chw(np.stack(targets)),
        masks=torch.from_numpy(np.stack(masks))[:, None].float().contiguous(),
        w2c_blender=np.asarray(first.lighting.w2c_blender, np.float64),
    )


def _chw(arr: np.ndarray) -> Tensor:
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(0, 3, 1, 2).float().contiguous()


# --- the lightings ----------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class _Lighting:
    """One relighting job: its file stem, label, world-map preview and encoded maps."""

    key: str
    label: str
    kind: Literal["target", "extra", "turntable"]
    world_rgb: np.ndarray | None  # [He, We, 3] uint8 preview, once per map
    maps: LightingMaps  # [1, 3, S, S] E_L and E_H


def _label(lt: EnvmapLighting) -> str:
    parts = [lt.source.stem]
    if lt.flip:
        parts.append("mirrored")
    if lt.yaw_step and lt.num_steps > 1:
        parts.append(f"yaw {lt.yaw_step}/{lt.num_steps} turn")
    if lt.strength != 1.0:
        parts.append(f"strength {lt.strength:g}")
    return ", ".join(parts)


def _preview(env: Any) -> np.ndarray:
    from gaffer_envmap.preview import tonemap_preview

    radiance = np.asarray(env.radiance_linear, np.float32)
    step = max(radiance.shape[0] // 64, 1)  # a 128 x 64 thumbnail is plenty for the report
    return tonemap_preview(radiance[::step, ::step])


class _Envmaps:
    """Each env-map file read once per run, then augmented as the renderer did (cf. `pair_lighting`)."""

    def __init__(self) -> None:
        self._read: dict[Path, Any] = {}

    def get(self, lt: EnvmapLighting) -> Any:
        from gaffer_envmap import AugmentSpec, EnvironmentMap
        from gaffer_envmap.io import read_envmap

        if lt.source not in self._read:
            try:
                self._read[lt.source] = read_envmap(lt.source, sanitize="zero")
            except (OSError, ValueError) as exc:
                raise DatasetError(
                    f"Could not read the environment map `{lt.source}` of `--example`: {exc}"
                ) from exc
        spec = AugmentSpec(flip=lt.flip, yaw_step=lt.yaw_step, num_steps=lt.num_steps)
        env = spec.apply(self._read[lt.source])
        if lt.strength != 1.0:
            radiance = np.asarray(env.radiance_linear) * np.float32(lt.strength)
            env = EnvironmentMap(radiance_linear=radiance)
        return env


def _turntable_hdri(name: str | None) -> tuple[str, Any]:
    """The turntable's bundled HDRI (`DemoConfig.turntable_hdri`) and its map."""
    from gaffer_envmap import directionality
    from gaffer_envmap.bundled import bundled_hdris, read_bundled_hdri

    names = sorted(bundled_hdris())
    if name is not None:
        if name not in names:
            raise ConfigError(
                f"`turntable_hdri` (--turntable-hdri) is {name!r}; expected one of {names}."
            )
        return name, read_bundled_hdri(name)
    maps = {n: read_bundled_hdri(n) for n in names}
    best = max(names, key=lambda n: directionality(maps[n], about_up=True))
    return best, maps[best]


def _lightings(
    example: _Example, config: DemoConfig, size: int, compat: CompatMode
) -> list[_Lighting]:
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.bundled import bundled_hdris, read_bundled_hdri

    envmaps = _Envmaps()
    w2c = torch.tensor(example.w2c_blender[None])  # [1, 3, 4], the input view's camera
    jobs: list[_Lighting] = []
    for p in example.pairs:
        lt = p.lighting
        if not isinstance(lt, EnvmapLighting):  # checked in _read_example
            raise DatasetError(f"`{p.name}` has no environment map.")
        env = envmaps.get(lt)
        # Neural Gaffer §3.2: the target map rotated into the input camera's frame, then E_L / E_H
        m = lighting_from_envmap(env, w2c, size=size, compat=compat)
        key = f"{p.target_lighting:03d}_{lt.source.stem}"
        jobs.append(
            _Lighting(key=key, label=_label(lt), kind="target", world_rgb=_preview(env), maps=m)
        )
    if config.extra_hdris:
        scored = {p.lighting.source.stem for p in example.pairs}  # type: ignore[union-attr]
        for name in sorted(set(bundled_hdris()) - scored):
            env = read_bundled_hdri(name)
            m = lighting_from_envmap(env, w2c, size=size, compat=compat)
            jobs.append(
                _Lighting(
                    key=f"extra_{name}", label=name, kind="extra", world_rgb=_preview(env), maps=m
                )
            )
    if config.frames:
        name, env = _turntable_hdri(config.turntable_hdri)
        n = config.frames
        spin = torch.arange(n, dtype=torch.float64) * (360.0 / n)
        m = lighting_from_envmap(
            env, w2c.expand(n, -1, -1), size=size, compat=compat, spin_deg=spin
        )
        for k in range(n):
            jobs.append(
                _Lighting(
                    key=f"frame_{k:03d}",
                    label=f"{name}, spun {float(spin[k]):.0f} deg about world up",
                    kind="turntable",
                    world_rgb=None,
                    maps=LightingMaps(ldr=m.ldr[k : k + 1], hdr=m.hdr[k : k + 1]),
                )
            )
    return jobs


# --- sampling, scoring, writing ---------------------------------------------------------------


def _sample(
    pipe: RelightPipeline,
    image: Tensor,
    mask: Tensor | None,
    jobs: Sequence[_Lighting],
    sampling: SamplingConfig,
    config: DemoConfig,
    on_batch: Callable[[int, int], None] | None = None,
) -> tuple[Tensor, list[float]]:
    """`[N, 3, S, S]` 8-bit-quantised relit images, and the wall time of every batch."""
    out: list[Tensor] = []
    seconds: list[float] = []
    for lo in range(0, len(jobs), config.batch_size):
        chunk = jobs[lo : lo + config.batch_size]
        cond = RelightingConditions(
            image=image.expand(len(chunk), -1, -1, -1),
            lighting=LightingMaps(
                ldr=torch.cat([j.maps.ldr for j in chunk]),
                hdr=torch.cat([j.maps.hdr for j in chunk]),
            ),
            mask=None if mask is None else mask.expand(len(chunk), -1, -1, -1),
        )
        t0 = time.perf_counter()
        # one seed for every image: a result does not depend on its batch, and the turntable's
        # noise stays still while its light moves (less flicker)
        result = pipe(cond, sampling, seeds=[config.seed] * len(chunk))
        seconds.append(time.perf_counter() - t0)
        out.append(quantize_8bit(result.images.float().cpu()))
        done = lo + len(chunk)
        logger.info("relit %d/%d images (%.2f s for this batch)", done, len(jobs), seconds[-1])
        if on_batch is not None:
            on_batch(done, len(jobs))
    return torch.cat(out), seconds


def _uint8(image: Tensor) -> np.ndarray:
    """`[3, H, W]` in [0, 1] -> `[H, W, 3]` uint8."""
    return (image.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255.0).round().astype(np.uint8)


def _write_png(path: Path, rgb: np.ndarray) -> None:
    from gaffer_envmap.atomic import atomic_path

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Image.fromarray(rgb).save(tmp, format="PNG")


def _write_text(path: Path, text: str) -> None:
    from gaffer_envmap.atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _write_gif(path: Path, frames: Sequence[np.ndarray], fps: float) -> None:
    from gaffer_envmap.atomic import atomic_path

    images = [Image.fromarray(f) for f in frames]
    with atomic_path(path) as tmp:
        images[0].save(
            tmp,
            format="GIF",
            save_all=True,
            append_images=images[1:],
            duration=round(1000 / fps),
            loop=0,
        )


def _side_by_side(*images: np.ndarray, scale: int = GIF_SCALE) -> np.ndarray:
    row = np.concatenate(images, axis=1)
    return row.repeat(scale, axis=0).repeat(scale, axis=1)


DEMO_OUTPUTS = frozenset(
    {
        "inputs",
        "lighting",
        "relit",
        "ground_truth",
        "turntable",
        "turntable.gif",
        "overview.png",
        "metrics.json",
        "report.html",
    }
)
"""What the demo writes at the top of its folder. A rerun replaces exactly these, all at once; other
entries (gaffer-envmap's `envmap/` demo, a user's notes) are carried into the new folder."""


def _check_out(out: Path) -> Path:
    """`out` can hold the demo: a folder or absent, in a writable place (checked before any work)."""
    from gaffer_diffusion import _cli_checks

    out = Path(out).expanduser()
    if out.exists() and not out.is_dir():
        raise ConfigError(
            f"`--out` {out} is a file, not a folder. Pass a folder for the demo's images and "
            "report (it is created if missing)."
        )
    _cli_checks.replaceable_dir("--out", out)
    return out


def _scores(report: MetricsReport, i: int) -> dict[str, Any]:
    item = report.items[i]
    return {
        "object_raw": None if item.object_raw is None else asdict(item.object_raw),
        "object_aligned": None if item.object_aligned is None else asdict(item.object_aligned),
        "raw": asdict(item.raw),
        "aligned_image": asdict(item.aligned_image),
        "aligned_mask": None if item.aligned_mask is None else asdict(item.aligned_mask),
    }


def _means(report: MetricsReport) -> dict[str, Any]:
    return {
        "object_raw": None if report.mean_object_raw is None else asdict(report.mean_object_raw),
        "object_aligned": None
        if report.mean_object_aligned is None
        else asdict(report.mean_object_aligned),
        "raw": asdict(report.mean_raw),
        "aligned_image": asdict(report.mean_aligned_image),
        "aligned_mask": None
        if report.mean_aligned_mask is None
        else asdict(report.mean_aligned_mask),
    }


@dataclass(frozen=True, kw_only=True)
class _Timings:
    load_model_s: float
    prepare_s: float
    sampling_s: float
    batches_s: list[float] = field(default_factory=list)
    metrics_s: float = 0.0
    write_s: float = 0.0
    total_s: float = 0.0
    images: int = 0

    def as_json(self) -> dict[str, Any]:
        per = self.sampling_s / max(self.images, 1)
        return {
            "load_model_s": round(self.load_model_s, 3),
            "prepare_s": round(self.prepare_s, 3),
            "sampling_s": round(self.sampling_s, 3),
            "sampling_per_image_s": round(per, 4),
            "sampling_batches_s": [round(s, 3) for s in self.batches_s],
            "metrics_s": round(self.metrics_s, 3),
            "write_s": round(self.write_s, 3),
            "total_s": round(self.total_s, 3),
        }


def run_demo(
    config: DemoConfig, *, on_batch: Callable[[int, int], None] | None = None
) -> DemoResult:
    """Relight the example object, score it, and write images, a GIF, `metrics.json` and a report.

    Args:
        config: what to relight and where to write (see `DemoConfig`).
        on_batch: called as `on_batch(images_done, images_total)` after every sampling call.

    Returns:
        A `DemoResult` with the written paths, the mean scores and the wall time.

    Raises:
        ConfigError: `out` is a file, or `checkpoint` is not in our format.
        CheckpointNotFoundError: `checkpoint` (or, without one, gaffer-tiny's weights) is missing.
        DatasetError: the example folder is not a usable gaffer-data render.
        MissingDependencyError: without gaffer-data (`pip install "gaffer-diffusion[eval]"`).

    Example:
        >>> from gaffer_diffusion.demo import DemoConfig, run_demo
        >>> result = run_demo(DemoConfig(out=Path("out/demo")))  # doctest: +SKIP
        >>> result.report_html  # doctest: +SKIP
        PosixPath('out/demo/report.html')
    """
    t_start = time.perf_counter()
    out = _check_out(config.out)
    loaded = load_model(config.checkpoint)
    pipe = RelightPipeline(loaded.model, RuntimeConfig(device=config.device))
    t_loaded = time.perf_counter()
    size = loaded.model.config.resolution
    sampling = sampling_for(
        loaded,
        config.num_inference_steps,
        config.guidance_scale,
        config.average_samples,
        config.mirror_average,
    )

    example_root = (
        Path(config.example) if config.example is not None else pretrained.example_dataset_path()
    )
    compat = config.compat or loaded.suggested_compat or "neural-gaffer"
    fraction = config.object_fraction or loaded.suggested_object_fraction
    example = _read_example(example_root, config.input_lighting, size, fraction)
    jobs = _lightings(example, config, size, compat)
    t_prepared = time.perf_counter()

    relit, batch_seconds = _sample(
        pipe,
        example.input_rgb,
        example.input_alpha if config.keep_background else None,
        jobs,
        sampling,
        config,
        on_batch,
    )
    t_sampled = time.perf_counter()

    n_gt = len(example.pairs)
    perceptual, reason = None, None
    try:
        perceptual = load_perceptual()
    except MetricUnavailableError as exc:
        reason = str(exc)
        logger.warning("perceptual metric unavailable: %s", reason)
    names = [j.key for j in jobs[:n_gt]]
    model_report = evaluate_images(
        relit[:n_gt], example.targets, mask=example.masks, names=names, perceptual=perceptual
    )
    baseline = evaluate_images(
        example.input_rgb.expand(n_gt, -1, -1, -1).contiguous(),
        example.targets,
        mask=example.masks,
        names=names,
        perceptual=perceptual,
    )
    t_scored = time.perf_counter()

    # complete or absent (issue 17): built in a hidden sibling, renamed over an earlier run at the end
    with atomic_dir(out, owned=DEMO_OUTPUTS) as stage:
        files = _write_images(stage, example, jobs, relit, config)
        t_written = time.perf_counter()
        timings = _Timings(
            load_model_s=t_loaded - t_start,
            prepare_s=t_prepared - t_loaded,
            sampling_s=t_sampled - t_prepared,
            batches_s=batch_seconds,
            metrics_s=t_scored - t_sampled,
            write_s=t_written - t_scored,
            total_s=t_written - t_start,
            images=len(jobs),
        )
        settings = _settings(config, loaded, pipe, sampling, example_root, example, len(jobs))
        settings["lighting_encoding"] = f"gaffer-envmap, compat={compat!r}"
        settings["framing"] = (
            "whole render"
            if fraction is None
            else f"object-centred square crop, object spans {fraction:g} of the side"
        )
        perceptual_info = {
            "name": None if perceptual is None else perceptual.name,
            "source": None if perceptual is None else perceptual.source,
            "unavailable_reason": reason,
        }
        metrics = _metrics_document(
            settings=settings,
            timings=timings,
            perceptual=perceptual_info,
            model_report=model_report,
            baseline=baseline,
            example=example,
            jobs=jobs,
            files=files,
            config=config,
        )
        _write_text(stage / "metrics.json", json_dumps(metrics, indent=2) + "\n")
        content = _report_content(metrics, jobs, files, model_report, baseline, perceptual_info)
        _write_text(stage / "report.html", render_html(content))
    metrics_json, report_html = out / "metrics.json", out / "report.html"
    seconds = time.perf_counter() - t_start
    logger.info("demo finished in %.1f s: %s", seconds, report_html)
    return DemoResult(
        out=out,
        report_html=report_html,
        metrics_json=metrics_json,
        turntable_gif=out / files["turntable"]["gif"] if config.frames else None,
        images=len(jobs),
        seconds=seconds,
        mean_relit=model_report.mean_raw,
        mean_input=baseline.mean_raw,
        summary=metrics["summary"],
    )


def _metrics_document(
    *,
    settings: dict[str, Any],
    timings: _Timings,
    perceptual: dict[str, Any],
    model_report: MetricsReport,
    baseline: MetricsReport,
    example: _Example,
    jobs: Sequence[_Lighting],
    files: dict[str, Any],
    config: DemoConfig,
) -> dict[str, Any]:
    """The contents of `metrics.json` (schema "gaffer.demo_metrics")."""
    return {
        "schema": METRICS_SCHEMA,
        "schema_version": METRICS_SCHEMA_VERSION,
        "producer": {"package": "gaffer-diffusion", "version": __version__},
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "settings": settings,
        "timings": timings.as_json(),
        "perceptual": perceptual,
        "summary": _summary(model_report, baseline),
        "closer_than_input": closer_than(model_report, baseline),
        "means": {
            "relit": _means(model_report),
            "baselines": {
                "input": _means(baseline),
                "note": "the unrelit input scored against each target: 'object_raw' / 'raw' as "
                "it is, 'object_aligned' / 'aligned_image' / 'aligned_mask' channel-aligned to "
                "the target; 'object_*' are scored over the object mask (lead), the rest over the "
                "full frame",
            },
        },
        "items": [
            {
                "name": jobs[i].key,
                "lighting": jobs[i].label,
                "pair": example.pairs[i].name,
                "files": files[jobs[i].key],
                "relit": _scores(model_report, i),
                "baseline_input": _scores(baseline, i),
            }
            for i in range(len(example.pairs))
        ],
        "extra": [
            {"name": j.key, "lighting": j.label, "files": files[j.key]}
            for j in jobs
            if j.kind == "extra"
        ],
        "turntable": None
        if not config.frames
        else {
            "lighting": next(j.label for j in jobs if j.kind == "turntable").split(",")[0],
            "frames": config.frames,
            "fps": config.fps,
            "gif": files["turntable"]["gif"],
            "frame_pngs": files["turntable"]["frames"],
        },
    }


def _summary(model_report: MetricsReport, baseline: MetricsReport) -> str:
    """The headline: object-mask PSNR relit vs unrelit, then full frame."""
    m, b = model_report, baseline
    text = ""
    if (
        m.mean_object_raw is not None
        and b.mean_object_raw is not None
        and m.mean_object_aligned is not None
        and b.mean_object_aligned is not None
    ):
        share = closer_than(m, b)
        text = (
            f"object mask: PSNR {m.mean_object_raw.psnr:.2f} dB relit vs {b.mean_object_raw.psnr:.2f} "
            f"dB unrelit; aligned {m.mean_object_aligned.psnr:.2f} vs {b.mean_object_aligned.psnr:.2f} "
            f"dB; closer than the input on {100 * (share or 0):.0f}% of lightings; "
        )
    return text + f"full frame: {m.mean_raw.psnr:.2f} dB relit vs {b.mean_raw.psnr:.2f} dB unrelit"


def _write_images(
    out: Path, example: _Example, jobs: Sequence[_Lighting], relit: Tensor, config: DemoConfig
) -> dict[str, Any]:
    """Every PNG, the overview sheet and the GIF; returns relative paths per job key."""
    from gaffer_envmap.preview import contact_sheet

    files: dict[str, Any] = {}
    input_png = "inputs/input.png"
    input_u8 = _uint8(example.input_rgb[0])
    _write_png(out / input_png, input_u8)
    sheet: list[list[tuple[str, np.ndarray]]] = []
    frames: list[np.ndarray] = []
    frame_pngs: list[str] = []
    for k, job in enumerate(jobs):
        relit_u8 = _uint8(relit[k])
        ldr_u8, hdr_u8 = _uint8(job.maps.ldr[0]), _uint8(job.maps.hdr[0])
        if job.kind == "turntable":
            rel = f"turntable/{job.key}.png"
            _write_png(out / rel, relit_u8)
            frame_pngs.append(rel)
            frames.append(_side_by_side(ldr_u8, relit_u8))
            continue
        entry = {
            "input": input_png,
            "world": f"lighting/{job.key}_world.png",
            "ldr": f"lighting/{job.key}_ldr.png",
            "hdr": f"lighting/{job.key}_hdr.png",
            "relit": f"relit/{job.key}.png",
        }
        if job.world_rgb is not None:
            _write_png(out / entry["world"], job.world_rgb)
        _write_png(out / entry["ldr"], ldr_u8)
        _write_png(out / entry["hdr"], hdr_u8)
        _write_png(out / entry["relit"], relit_u8)
        row: list[tuple[str, np.ndarray | None]] = [("", job.world_rgb), ("E_L", ldr_u8)]
        row.append(("E_H", hdr_u8))
        row += [("input", input_u8), ("relit", relit_u8)]
        if job.kind == "target":
            entry["ground_truth"] = f"ground_truth/{job.key}.png"
            gt_u8 = _uint8(example.targets[k])
            _write_png(out / entry["ground_truth"], gt_u8)
            row.append(("ground truth", gt_u8))
        row[0] = (job.label if job.kind == "target" else f"{job.label} (no render)", job.world_rgb)
        sheet.append([(label, im) for label, im in row if im is not None])
        files[job.key] = entry
    _write_png(out / "overview.png", contact_sheet(sheet, cell=128))
    files["turntable"] = {"gif": None, "frames": frame_pngs}
    if frames:
        _write_gif(out / "turntable.gif", frames, config.fps)
        files["turntable"]["gif"] = "turntable.gif"
    return files


def _settings(
    config: DemoConfig,
    loaded: LoadedModel,
    pipe: RelightPipeline,
    sampling: SamplingConfig,
    example_root: Path,
    example: _Example,
    images: int,
) -> dict[str, Any]:
    return {
        "model": loaded.name,
        "checkpoint": str(loaded.source),
        "resolution": loaded.model.config.resolution,
        "example": str(example_root),
        "object": example.pairs[0].object_id,
        "view": example.pairs[0].view_index,
        "input_image": str(example.pairs[0].input_image),
        "scored_lightings": len(example.pairs),
        "images": images,
        "scheduler": sampling.scheduler,
        "num_inference_steps": sampling.num_inference_steps,
        "guidance_scale": sampling.guidance_scale,
        "average_samples": sampling.average_samples,
        "mirror_average": sampling.mirror_average,
        "seed": config.seed,
        "batch_size": config.batch_size,
        "lighting_encoding": "",
        "device": pipe.runtime.device,
        "dtype": pipe.runtime.dtype,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "gaffer_diffusion": __version__,
        "prediction": "8-bit quantised on white; scored over the object mask first, then over "
        "the full frame (authors' protocol); "
        + (
            "the input kept outside its alpha"
            if config.keep_background
            else "the model's full frame"
        ),
        "alignment": "pred_c * mean(gt_c) / mean(pred_c), means over the whole image or the mask",
    }


def _row_scores(item: dict[str, Any]) -> tuple[tuple[str, ImageScores], ...]:
    def sc(d: dict[str, Any] | None) -> ImageScores | None:
        return None if d is None else ImageScores(**d)

    rows = [
        ("relit, object mask", sc(item["relit"].get("object_raw"))),
        ("relit, object mask, aligned", sc(item["relit"].get("object_aligned"))),
        ("input, object mask (baseline)", sc(item["baseline_input"].get("object_raw"))),
        (
            "input aligned to target, object mask (baseline)",
            sc(item["baseline_input"].get("object_aligned")),
        ),
        ("relit", sc(item["relit"]["raw"])),
        ("relit, aligned (image)", sc(item["relit"]["aligned_image"])),
        ("relit, aligned (mask)", sc(item["relit"]["aligned_mask"])),
        ("input (baseline)", sc(item["baseline_input"]["raw"])),
        ("input aligned to target (baseline)", sc(item["baseline_input"]["aligned_image"])),
    ]
    return tuple((k, v) for k, v in rows if v is not None)


def _report_content(
    metrics: dict[str, Any],
    jobs: Sequence[_Lighting],
    files: dict[str, Any],
    model_report: MetricsReport,
    baseline: MetricsReport,
    perceptual: dict[str, Any],
) -> ReportContent:
    items = {it["name"]: it for it in metrics["items"]}
    rows = []
    for job in jobs:
        if job.kind == "turntable":
            continue
        f = files[job.key]
        rows.append(
            LightingRow(
                key=job.key,
                label=job.label,
                world=f["world"],
                ldr=f["ldr"],
                hdr=f["hdr"],
                input=f["input"],
                relit=f["relit"],
                ground_truth=f.get("ground_truth"),
                scores=_row_scores(items[job.key]) if job.key in items else (),
            )
        )
    means: list[tuple[str, ImageScores]] = []
    if model_report.mean_object_raw is not None and model_report.mean_object_aligned is not None:
        means += [
            ("relit, object mask", model_report.mean_object_raw),
            ("relit, object mask, channel-aligned", model_report.mean_object_aligned),
        ]
    if baseline.mean_object_raw is not None and baseline.mean_object_aligned is not None:
        means += [
            ("baseline: unrelit input, object mask", baseline.mean_object_raw),
            ("baseline: input channel-aligned, object mask", baseline.mean_object_aligned),
        ]
    means += [
        ("relit, full frame", model_report.mean_raw),
        ("relit, channel-aligned (whole image)", model_report.mean_aligned_image),
    ]
    if model_report.mean_aligned_mask is not None:
        means.append(("relit, channel-aligned (mask)", model_report.mean_aligned_mask))
    means += [
        ("baseline: unrelit input", baseline.mean_raw),
        ("baseline: input channel-aligned to the target", baseline.mean_aligned_image),
    ]
    if baseline.mean_aligned_mask is not None:
        means.append(("baseline: input channel-aligned (mask)", baseline.mean_aligned_mask))
    s = metrics["settings"]
    name = perceptual["name"]
    note = None
    if name == "stlpips-alex":
        note = (
            "stlpips-alex is shift-tolerant LPIPS (AlexNet), not standard LPIPS; lower is better."
        )
    elif name is None:
        note = f"Perceptual metric unavailable: {perceptual['unavailable_reason']}"
    tt = metrics["turntable"]
    timings = metrics["timings"]
    return ReportContent(
        title=f"gaffer relighting demo: {s['model']} on {s['object']}",
        settings=tuple((k, str(v)) for k, v in s.items()),
        timings=(
            ("load model", f"{timings['load_model_s']:.2f} s"),
            ("read example + encode lighting", f"{timings['prepare_s']:.2f} s"),
            ("sampling, all images", f"{timings['sampling_s']:.2f} s ({s['images']} images)"),
            ("sampling, per image", f"{timings['sampling_per_image_s']:.3f} s"),
            ("metrics", f"{timings['metrics_s']:.2f} s"),
            ("writing images", f"{timings['write_s']:.2f} s"),
            ("total", f"{timings['total_s']:.2f} s"),
        ),
        perceptual_label=name or "perceptual (n/a)",
        perceptual_note=note,
        means=tuple(means),
        rows=tuple(rows),
        turntable_gif=None if tt is None else tt["gif"],
        turntable_label=None if tt is None else f"{tt['lighting']}, {tt['frames']} frames",
        created_utc=metrics["created_utc"],
        summary=metrics["summary"],
    )
