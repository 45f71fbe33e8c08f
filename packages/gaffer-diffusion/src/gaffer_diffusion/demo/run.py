"""`run_demo`: load, read, sample, score, then write the whole folder at once; `DemoResult`."""

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from gaffer_diffusion import pretrained
from gaffer_diffusion._atomic_dir import atomic_dir
from gaffer_diffusion._json import json_dumps
from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.example import _read_example
from gaffer_diffusion.demo.lightings import _lightings
from gaffer_diffusion.demo.metrics_document import _metrics_document, _settings, _Timings
from gaffer_diffusion.demo.model import load_model, sampling_for
from gaffer_diffusion.demo.report_content import _report_content
from gaffer_diffusion.demo.sampling import _sample
from gaffer_diffusion.demo.writing import _write_images, _write_text
from gaffer_diffusion.errors import ConfigError, MetricUnavailableError
from gaffer_diffusion.metrics import ImageScores, evaluate_images, load_perceptual
from gaffer_diffusion.pipelines import RuntimeConfig
from gaffer_diffusion.report import render_html

logger = logging.getLogger("gaffer_diffusion.demo")  # the name log lines carried before the split


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
    # the runtime `gaffer-diffusion relight` builds from its defaults (`--dtype auto`)
    runtime = RuntimeConfig(device=config.device, dtype=config.dtype)
    loaded = load_model(config.checkpoint, runtime=runtime)
    pipe = loaded.pipeline
    t_loaded = time.perf_counter()
    size = loaded.model.config.resolution
    compat = config.compat or loaded.default_sampling.compat
    sampling = sampling_for(
        loaded,
        config.num_inference_steps,
        config.guidance_scale,
        config.average_samples,
        config.mirror_average,
        compat,
    )

    example_root = (
        Path(config.example) if config.example is not None else pretrained.example_dataset_path()
    )
    fraction = config.object_fraction or loaded.default_sampling.object_fraction
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

    # complete or absent (a killed run leaves no half report): built in a hidden sibling, renamed over an earlier run at the end
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
        _write_text(stage / "metrics.json", json_dumps(metrics.as_json(), indent=2) + "\n")
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
        summary=metrics.summary,
    )
