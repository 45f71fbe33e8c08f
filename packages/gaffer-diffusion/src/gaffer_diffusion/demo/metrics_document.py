"""The contents of `metrics.json` (schema "gaffer.demo_metrics"): settings, timings, scores.

`_metrics_document` builds a frozen `_MetricsDocument`; `run.py` writes its `as_json()` as
`metrics.json` and `report_content.py` reads the same object for `report.html`."""

import datetime
import platform
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch

from gaffer_diffusion._version import __version__
from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.example import _Example
from gaffer_diffusion.demo.lightings import _Lighting
from gaffer_diffusion.demo.model import LoadedModel
from gaffer_diffusion.metrics import MetricsReport, closer_than
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig

METRICS_SCHEMA = "gaffer.demo_metrics"


METRICS_SCHEMA_VERSION = "1.0"


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
class _MetricsDocument:
    """The metrics document, as written to `metrics.json` (`as_json`) and read by the report.

    The top level is typed; the nested parts (settings, rounded timings, perceptual metric, means,
    items, extras, turntable) are the JSON objects `metrics.json` holds, as they are written.
    """

    created_utc: str
    settings: dict[str, Any]
    timings: dict[str, Any]  # `_Timings.as_json()`: rounded, as the report shows them
    perceptual: dict[str, Any]
    summary: str
    closer_than_input: float | None
    means: dict[str, Any]
    items: list[dict[str, Any]]
    extra: list[dict[str, Any]]
    turntable: dict[str, Any] | None

    def as_json(self) -> dict[str, Any]:
        """The contents of `metrics.json` (schema "gaffer.demo_metrics"), keys in file order."""
        return {
            "schema": METRICS_SCHEMA,
            "schema_version": METRICS_SCHEMA_VERSION,
            "producer": {"package": "gaffer-diffusion", "version": __version__},
            "created_utc": self.created_utc,
            "settings": self.settings,
            "timings": self.timings,
            "perceptual": self.perceptual,
            "summary": self.summary,
            "closer_than_input": self.closer_than_input,
            "means": self.means,
            "items": self.items,
            "extra": self.extra,
            "turntable": self.turntable,
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
) -> _MetricsDocument:
    """The metrics document (schema "gaffer.demo_metrics"); `as_json()` is `metrics.json`."""
    return _MetricsDocument(
        created_utc=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        settings=settings,
        timings=timings.as_json(),
        perceptual=perceptual,
        summary=_summary(model_report, baseline),
        closer_than_input=closer_than(model_report, baseline),
        means={
            "relit": _means(model_report),
            "baselines": {
                "input": _means(baseline),
                "note": "the unrelit input scored against each target: 'object_raw' / 'raw' as "
                "it is, 'object_aligned' / 'aligned_image' / 'aligned_mask' channel-aligned to "
                "the target; 'object_*' are scored over the object mask (lead), the rest over the "
                "full frame",
            },
        },
        items=[
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
        extra=[
            {"name": j.key, "lighting": j.label, "files": files[j.key]}
            for j in jobs
            if j.kind == "extra"
        ],
        turntable=None
        if not config.frames
        else {
            "lighting": next(j.label for j in jobs if j.kind == "turntable").split(",")[0],
            "frames": config.frames,
            "fps": config.fps,
            "gif": files["turntable"]["gif"],
            "frame_pngs": files["turntable"]["frames"],
        },
    )


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
