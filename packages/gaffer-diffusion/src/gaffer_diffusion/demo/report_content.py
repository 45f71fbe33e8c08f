"""What `report.html` shows, read from the metrics document (`gaffer_diffusion.report` renders it)."""

from collections.abc import Sequence
from typing import Any

from gaffer_diffusion.demo.lightings import _Lighting
from gaffer_diffusion.demo.metrics_document import _MetricsDocument
from gaffer_diffusion.metrics import ImageScores, MetricsReport
from gaffer_diffusion.report import LightingRow, ReportContent


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
    metrics: _MetricsDocument,
    jobs: Sequence[_Lighting],
    files: dict[str, Any],
    model_report: MetricsReport,
    baseline: MetricsReport,
    perceptual: dict[str, Any],
) -> ReportContent:
    items = {it["name"]: it for it in metrics.items}
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
    s = metrics.settings
    name = perceptual["name"]
    note = None
    if name == "stlpips-alex":
        note = (
            "stlpips-alex is shift-tolerant LPIPS (AlexNet), not standard LPIPS; lower is better."
        )
    elif name is None:
        note = f"Perceptual metric unavailable: {perceptual['unavailable_reason']}"
    tt = metrics.turntable
    timings = metrics.timings
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
        created_utc=metrics.created_utc,
        summary=metrics.summary,
    )
