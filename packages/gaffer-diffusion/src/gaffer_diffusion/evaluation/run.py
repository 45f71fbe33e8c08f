"""`evaluate_dataset`: relight every pair in batches and score it against its ground truth."""

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
import torch
from torch import Tensor

from gaffer_diffusion.conditioning import RelightingConditions
from gaffer_diffusion.errors import DatasetError
from gaffer_diffusion.evaluation.images import (
    _to_chw,
    pair_crop_box,
    read_mask,
    read_rgba_on_white,
)
from gaffer_diffusion.evaluation.lighting import pair_lighting
from gaffer_diffusion.evaluation.records import (
    DatasetEvaluation,
    EncodedLightingFiles,
    EvalPair,
    EvaluationConfig,
)
from gaffer_diffusion.images import quantize_8bit, to_uint8
from gaffer_diffusion.metrics import (
    MetricsReport,
    PerceptualMetric,
    combine_reports,
    evaluate_images,
    load_perceptual,
)
from gaffer_diffusion.pipelines import RelightPipeline, relight_built_batches
from gaffer_envmap.writers import write_png


class _BatchImages(NamedTuple):
    """What `evaluate_dataset` read for one batch besides its conditions: `[S, S, 3]` inputs and
    targets, `[S, S]` masks (float32 in [0, 1])."""

    inputs: list[np.ndarray]
    targets: list[np.ndarray]
    masks: list[np.ndarray]


def evaluate_dataset(
    pipe: RelightPipeline,
    pairs: Sequence[EvalPair],
    config: EvaluationConfig | None = None,
    *,
    perceptual: PerceptualMetric | Literal["auto"] | None = "auto",
    settings: dict[str, Any] | None = None,
    on_batch: Callable[[int, int], None] | None = None,
    normals_of: Callable[[EvalPair, tuple[int, int, int] | None, int], Tensor] | None = None,
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
        normals_of: `(pair, crop box, size) -> [3, size, size]` camera-frame normals of the pair's
            input for the hints (`RelightingConditions.normals`), e.g. the render's true normals
            for the oracle row of the re-shading benchmark; None: the model's own geometry.

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
        read: dict[int, _BatchImages] = {}  # filled by `build`, taken once its batch is relit

        def build(lo: int, hi: int) -> RelightingConditions:
            batch = pairs[lo:hi]
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
            read[lo] = _BatchImages(list(inputs), list(targets), masks)
            return RelightingConditions(
                image=_to_chw(list(inputs)),
                lighting=pair_lighting(batch, size, config.compat),
                mask=_to_chw(list(input_alphas)) if config.keep_background else None,
                normals=None
                if normals_of is None
                else torch.stack([normals_of(p, bx, size) for p, bx in zip(batch, boxes)]),
            )

        for relit in relight_built_batches(
            pipe,
            len(pairs),
            build,
            config.sampling,
            seeds=config.seed,
            batch_size=config.batch_size,
        ):
            batch = pairs[relit.start : relit.stop]
            inputs, targets, masks = read.pop(relit.start)
            pred = quantize_8bit(relit.output.images.float().cpu())
            if config.predictions_dir is not None:
                _save_predictions(config.predictions_dir, batch, pred)
            report = evaluate_images(
                pred,
                _to_chw(targets),
                mask=_to_chw(masks),
                names=[p.name for p in batch],
                perceptual=perceptual,
            )
            if config.baselines:
                baselines.append(
                    evaluate_images(
                        _to_chw(inputs),
                        _to_chw(targets),
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
        write_png(path, to_uint8(img))
