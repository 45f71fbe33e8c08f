"""`gaffer-diffusion evaluate`: relight a gaffer-data rendered dataset with a model and score it
(`--dataset`), or score predicted images against ground truth matched by name (`--pred/--gt`).
`_from_args.evaluate_request` checks every flag (and reads the masks, the dataset's pairs and checks
their maps) first; the bodies here take that request."""

from __future__ import annotations

import argparse

from gaffer_diffusion.cli._from_args import _check_envmaps as _check_envmaps
from gaffer_diffusion.cli._from_args import _read_dir_images, evaluate_request
from gaffer_diffusion.cli._requests import (
    EvaluateDatasetRequest,
    EvaluateFoldersRequest,
    EvaluateRequest,
    Reports,
)


def _evaluate(args: argparse.Namespace) -> int:
    return _run_evaluate(evaluate_request(args))


def _run_evaluate(request: EvaluateRequest) -> int:
    """Evaluate as `request` asks; returns the exit status."""
    if isinstance(request, EvaluateDatasetRequest):
        return _evaluate_dataset(request)
    return _evaluate_folders(request)


def _write_reports(reports: Reports, json_text: str, markdown: str) -> None:
    if reports.json:
        reports.json.write_text(json_text)
    if reports.markdown:
        reports.markdown.write_text(markdown + "\n")
    print(markdown)


def _evaluate_dataset(request: EvaluateDatasetRequest) -> int:
    from gaffer_diffusion.evaluation import EvaluationConfig, evaluate_dataset
    from gaffer_diffusion.pipelines import load_pipeline

    model, pairs = request.model, list(request.pairs)
    perceptual = request.reports.load_perceptual()
    model.runtime.device_name()  # a CUDA device torch cannot use is refused before the weights load
    pipe = load_pipeline(model.checkpoint, model.base_model, runtime=model.runtime.runtime_config())
    config = EvaluationConfig(
        sampling=model.sampling_config(),
        seed=model.seed,
        batch_size=model.batch_size,
        compat=model.compat,
        predictions_dir=request.save_predictions,
        progress=True,
        keep_background=not model.full_frame,
        object_fraction=request.object_fraction,
    )
    settings = {
        "dataset": str(request.dataset),
        "checkpoint": "gaffer-tiny (shipped)"
        if model.checkpoint is None
        else str(model.checkpoint),
        "base_model": None if model.base_model is None else str(model.base_model),
        "input_lighting": request.input_lighting,
    }
    result = evaluate_dataset(pipe, pairs, config, perceptual=perceptual, settings=settings)
    _write_reports(request.reports, result.to_json() + "\n", result.to_markdown())
    print(
        f"\n{len(pairs)} pairs in {result.seconds:.1f} s ({pipe.dtype_choice.note()}): "
        f"{result.summary()}"
    )
    return 0


def _evaluate_folders(request: EvaluateFoldersRequest) -> int:
    from gaffer_diffusion.metrics import evaluate_images

    names = list(request.names)
    pred = _read_dir_images(request.pred, names, "RGB")
    gt = _read_dir_images(request.gt, names, "RGB")
    perceptual = request.reports.load_perceptual()
    report = evaluate_images(pred, gt, mask=request.masks, names=names, perceptual=perceptual)
    _write_reports(request.reports, report.to_json(), report.to_markdown())
    return 0
