"""Render cost vs quality: seconds per image and PSNR against a high-sample reference.

For each resolution, the same objects, cameras and environment-map draws (same seed) are rendered once
with many samples and no denoiser (the reference), then at each (samples, denoiser, adaptive threshold)
setting. PSNR = 10 log10(1 / MSE) on the 8-bit display PNGs scaled to [0, 1], RGB composited on white
with their alpha (the paper's evaluation images), averaged over images. Seconds per image are the
worker's own timings (render + save, without Blender's ~1 s start per object).

Benchmark code, not part of the gaffer-data wheel: `bench_data_render.py` runs it through gaffer-data's
own render workers (`gaffer_data.render.runner.render_dataset`), and tests/benchmarks/test_render_bench.py
checks it on a 32 px scene. Not a benchmark itself (`nox -s bench` runs only `bench_*.py`).

Example:
    >>> import _render_bench as rb  # doctest: +SKIP
    >>> result = rb.bench_render(objects, pool, "bench/", rb.RenderBenchConfig(resolutions=(128,)))  # doctest: +SKIP
    >>> result.fastest_reaching(35.0)  # doctest: +SKIP
"""

import dataclasses
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gaffer_data.config import RenderConfig
from gaffer_data.dataset.reader import open_dataset
from gaffer_data.errors import ConfigError, RenderError
from gaffer_data.render.plan import PoolEntry
from gaffer_data.render.runner import RunOptions, render_dataset


@dataclass(frozen=True, kw_only=True)
class RenderBenchConfig:
    """What to measure.

    Attributes:
        resolutions: square image sides to measure.
        samples: samples per pixel to measure.
        denoise: denoiser settings to measure (OpenImageDenoise on / off).
        adaptive_thresholds: Cycles adaptive-sampling thresholds to measure (0 = off).
        reference_samples: samples of the reference (no denoiser, no adaptive sampling).
        views: views per object.
        lightings: environment-map renders per view.
        world_map_resolution: Cycles importance-map resolution (0 = automatic, as the paper).
        threads: Cycles threads (0 = all cores).
    """

    resolutions: tuple[int, ...] = (128, 256)
    samples: tuple[int, ...] = (16, 32, 64, 128)
    denoise: tuple[bool, ...] = (False, True)
    adaptive_thresholds: tuple[float, ...] = (0.01,)
    reference_samples: int = 1024
    views: int = 1
    lightings: int = 2
    world_map_resolution: int = 0
    threads: int = 0

    def __post_init__(self) -> None:
        if not self.resolutions or not self.samples or not self.denoise:
            raise ConfigError(
                "`resolutions`, `samples` and `denoise` must each list one value at least."
            )
        if self.reference_samples <= max(self.samples):
            raise ConfigError(
                f"`reference_samples`={self.reference_samples} must exceed every measured sample count "
                f"(max {max(self.samples)}); raise it (e.g. 8x the largest)."
            )


@dataclass(frozen=True, kw_only=True)
class BenchPoint:
    """One measured setting.

    Attributes:
        resolution: image side in pixels.
        samples: samples per pixel.
        denoise: whether the denoiser ran.
        adaptive_threshold: adaptive-sampling threshold (0 = off).
        seconds_per_image: mean worker time per image.
        images_per_second_per_core: throughput normalised by the cores Cycles used.
        psnr_db: mean PSNR against the reference, in dB (inf when identical).
    """

    resolution: int
    samples: int
    denoise: bool
    adaptive_threshold: float
    seconds_per_image: float
    images_per_second_per_core: float
    psnr_db: float


@dataclass(frozen=True, kw_only=True)
class RenderBenchResult:
    """All measured settings, plus the references' own cost.

    Attributes:
        config: what was measured.
        points: one entry per (resolution, samples, denoise, adaptive threshold).
        reference_seconds_per_image: worker time per reference image, per resolution.
        cores: the cores Cycles used.
        images: images per setting (objects x views x lightings).
    """

    config: RenderBenchConfig
    points: tuple[BenchPoint, ...]
    reference_seconds_per_image: tuple[tuple[int, float], ...]
    cores: int
    images: int

    def fastest_reaching(self, psnr_db: float, resolution: int | None = None) -> BenchPoint | None:
        """The cheapest setting with PSNR >= `psnr_db` (at `resolution`, if given), or None."""
        ok = [
            p
            for p in self.points
            if p.psnr_db >= psnr_db and (resolution is None or p.resolution == resolution)
        ]
        return min(ok, key=lambda p: p.seconds_per_image, default=None)


def _display_rgb(path: Path) -> np.ndarray:
    """`[H, W, 3]` float64 in [0, 1]: the PNG's RGB over white with its straight alpha."""
    from PIL import Image

    with Image.open(path) as im:
        rgba = np.asarray(im.convert("RGBA"), dtype=np.float64) / 255.0
    alpha = rgba[..., 3:]
    return rgba[..., :3] * alpha + (1.0 - alpha)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """10 log10(1 / MSE) for images in [0, 1] (inf when equal)."""
    mse = float(np.mean((np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(1.0 / mse)


def _render(
    objects: Sequence[tuple[str, Path]],
    pool: Sequence[PoolEntry],
    out: Path,
    config: RenderConfig,
) -> tuple[float, dict[tuple[str, str], Path]]:
    summary = render_dataset(objects, pool, out, config, RunOptions(progress=False, retries=0))
    if summary.failed:
        raise RenderError(
            f"benchmark render into `{out}` failed: {summary.failed[0].reason}; check the inputs."
        )
    images = {}
    for sample in open_dataset(out).iter_samples():
        images[(sample.object_id, sample.image_png.name)] = sample.image_png
    seconds = float(np.mean(summary.image_seconds)) if summary.image_seconds else math.nan
    return seconds, images


def bench_render(
    objects: Sequence[tuple[str, Path]],
    pool: Sequence[PoolEntry],
    work_dir: str | Path,
    bench: RenderBenchConfig | None = None,
) -> RenderBenchResult:
    """Measure seconds per image and PSNR vs a high-sample reference for every configured setting.

    Args:
        objects: `(object_id, mesh path)` pairs (a few: every setting renders all of them).
        pool: the lighting pool.
        work_dir: scratch folder for the renders (reused: settings already rendered are skipped, so
            their timings are only measured once; use a fresh folder for new timings).
        bench: what to measure.

    Returns:
        The measurements (`seconds_per_image` is NaN for settings found already rendered).

    Raises:
        RenderError: a render failed.
    """
    bench = bench or RenderBenchConfig()
    work = Path(work_dir)
    cores = bench.threads or (os.cpu_count() or 1)
    base = RenderConfig(
        views=bench.views,
        lightings=bench.lightings,
        area_light_render=False,
        world_map_resolution=bench.world_map_resolution,
        threads=bench.threads,
    )
    points, references = [], []
    images = 0
    for res in bench.resolutions:
        ref_cfg = dataclasses.replace(
            base,
            resolution=res,
            samples=bench.reference_samples,
            denoise=False,
            adaptive_threshold=0.0,
        )
        ref_seconds, ref_images = _render(objects, pool, work / f"ref_{res}", ref_cfg)
        references.append((res, ref_seconds))
        images = len(ref_images)
        reference = {key: _display_rgb(path) for key, path in ref_images.items()}
        for spp in bench.samples:
            for denoise in bench.denoise:
                for threshold in bench.adaptive_thresholds:
                    cfg = dataclasses.replace(
                        base,
                        resolution=res,
                        samples=spp,
                        denoise=denoise,
                        adaptive_threshold=threshold,
                    )
                    name = f"{res}px_{spp}spp_dn{int(denoise)}_ad{threshold:g}"
                    seconds, imgs = _render(objects, pool, work / name, cfg)
                    scores = [psnr(_display_rgb(imgs[key]), ref) for key, ref in reference.items()]
                    points.append(
                        BenchPoint(
                            resolution=res,
                            samples=spp,
                            denoise=denoise,
                            adaptive_threshold=threshold,
                            seconds_per_image=seconds,
                            images_per_second_per_core=1.0 / (seconds * cores),
                            psnr_db=float(np.mean(scores)),
                        )
                    )
    return RenderBenchResult(
        config=bench,
        points=tuple(points),
        reference_seconds_per_image=tuple(references),
        cores=cores,
        images=images,
    )
