"""`gaffer-diffusion evaluate`: relight a gaffer-data rendered dataset with a model and score it
(`--dataset`), or score predicted images against ground truth matched by name (`--pred/--gt`)."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import (
    _compat,
    _device,
    _load_pipeline,
    _object_fraction,
    _sampling,
)
from gaffer_diffusion.cli._flag_checks import _check_model_args, _check_sampling_args
from gaffer_diffusion.errors import ConfigError, InputValueError

if TYPE_CHECKING:
    import torch

logger = logging.getLogger("gaffer_diffusion.cli")  # the name log lines carried before the split


def _validate_evaluate(args: argparse.Namespace) -> None:
    for flag, path in (("--json", args.json), ("--markdown", args.markdown)):
        if path is not None:
            checks.writable_file(flag, path)
    if args.json is not None and args.markdown is not None:
        if args.json.absolute().resolve() == args.markdown.absolute().resolve():
            raise ConfigError(
                f"`--json` and `--markdown` are both {args.json}: one report would replace the "
                "other; pass two file names."
            )
    if args.no_perceptual and args.lpips_backbone is not None:
        raise ConfigError("Pass `--lpips-backbone` or `--no-perceptual`, not both.")
    if args.lpips_backbone is not None:
        checks.need_file("--lpips-backbone", args.lpips_backbone, "torchvision AlexNet weights")
    if args.dataset is None:
        for flag, path in (("--pred", args.pred), ("--gt", args.gt), ("--mask-dir", args.mask_dir)):
            if path is not None:
                checks.need_dir(flag, path, "a folder of images")
        return
    checks.need_dir("--dataset", args.dataset, "a gaffer-data render folder")
    if not (args.dataset / "dataset.json").is_file() and not (args.dataset / "objects").is_dir():
        raise InputValueError(
            f"`--dataset` {args.dataset} is not a gaffer-data dataset (no dataset.json, no "
            "objects/); pass the folder `gaffer-data render --out` wrote."
        )
    if args.envmaps is not None:
        checks.need_dir("--envmaps", args.envmaps, "the folder of the maps the dataset was lit by")
    checks.int_range("--limit", args.limit, 1, 2**31, "pairs to evaluate")
    if isinstance(args.input_lighting, int) and args.input_lighting < 0:
        raise ConfigError(
            f"`--input-lighting` is {args.input_lighting}; expected a lighting index >= 0 or 'area'."
        )
    if args.save_predictions is not None:
        checks.writable_dir("--save-predictions", args.save_predictions)
    _check_sampling_args(args)
    _object_fraction(args)
    _check_model_args(args)


def _read_dir_images(folder: Path, names: Sequence[str], channels: str) -> torch.Tensor:
    import numpy as np
    import torch
    from PIL import Image

    arrs = []
    for name in names:
        with Image.open(folder / name) as im:
            arrs.append(np.asarray(im.convert(channels), np.float32) / 255.0)
    for name, arr in zip(names, arrs, strict=True):
        if arr.shape != arrs[0].shape:
            raise InputValueError(
                f"`{folder / name}` has shape {arr.shape}, but `{folder / names[0]}` has "
                f"{arrs[0].shape}: every image must have the same size."
            )
    t = torch.from_numpy(np.stack(arrs))
    return t.permute(0, 3, 1, 2) if t.ndim == 4 else t[:, None]


def _perceptual_arg(args: argparse.Namespace) -> Any:
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual

    if args.no_perceptual:
        if args.lpips_backbone is not None:
            raise ConfigError("Pass `--lpips-backbone` or `--no-perceptual`, not both.")
        return None
    if args.lpips_backbone is None:
        return "auto"
    try:
        return load_perceptual(args.lpips_backbone)
    except MetricUnavailableError as exc:
        raise InputValueError(str(exc)) from exc


def _evaluate(args: argparse.Namespace) -> int:
    folders = args.pred is not None or args.gt is not None
    if args.dataset is not None and folders:
        raise ConfigError(
            "Pass either `--dataset DIR --checkpoint CKPT` (relight and score a rendered dataset) or "
            "`--pred DIR --gt DIR` (score existing predictions), not both."
        )
    if args.dataset is None and (args.pred is None or args.gt is None):
        raise ConfigError(
            "Pass `--dataset DIR --checkpoint CKPT`, or both `--pred DIR` and `--gt DIR`."
        )
    _validate_evaluate(args)  # every flag and file, before torch is imported or weights load
    if args.dataset is not None:
        return _evaluate_dataset(args)
    return _evaluate_folders(args)


def _check_envmaps(pairs: Sequence[Any], policy: str) -> None:
    """`--sanitize`: read each env map the pairs are lit by once with `policy`, before the model loads.

    The scoring (`gaffer_diffusion.evaluation`) reads the maps again with "zero", which yields the
    same pixels as every policy that passes here ("raise" sets only tiny negatives to 0, "strict"
    passes only clean maps), except "clamp" on a map holding +Inf: that is refused here rather than
    scored with a different map than asked for.
    """
    import numpy as np

    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.io import read_envmap

    sources = sorted({s for p in pairs if (s := getattr(p.lighting, "source", None)) is not None})
    for source in sources:
        try:
            env = read_envmap(source, sanitize=policy)  # type: ignore[arg-type]
        except NonFiniteError as exc:  # said as the flag, not as the API's `sanitize=` hint
            what = str(exc).split(" Pass `sanitize=")[0]
            raise InputValueError(
                f"{what} Pass `--sanitize zero` (or `clamp`) to repair the dataset's map "
                f"(`--sanitize {policy}` refused it), or fix the file."
            ) from exc
        if policy == "clamp" and not np.array_equal(
            env.radiance_linear, read_envmap(source, sanitize="zero").radiance_linear
        ):
            raise InputValueError(
                f"`{source}` holds +Inf pixels, which `--sanitize clamp` would keep bright but "
                "evaluate's scoring sets to 0; pass `--sanitize zero` or repair the map."
            )


def _evaluate_dataset(args: argparse.Namespace) -> int:
    from gaffer_diffusion.evaluation import EvaluationConfig, dataset_pairs, evaluate_dataset

    if args.batch_size < 1:
        raise ConfigError(f"`--batch-size` is {args.batch_size}; expected >= 1.")
    pairs = dataset_pairs(
        args.dataset,
        input_lighting=args.input_lighting,
        envmap_dirs=[args.envmaps] if args.envmaps is not None else [],
        limit=args.limit,
    )
    _check_envmaps(pairs, args.sanitize)  # before the model loads
    perceptual = _perceptual_arg(args)
    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    pipe = _load_pipeline(args)
    config = EvaluationConfig(
        sampling=_sampling(args),
        seed=args.seed,
        batch_size=args.batch_size,
        compat=_compat(args),
        predictions_dir=args.save_predictions,
        progress=True,
        keep_background=not args.full_frame,
        object_fraction=_object_fraction(args),
    )
    settings = {
        "dataset": str(args.dataset),
        "checkpoint": "gaffer-tiny (shipped)" if args.checkpoint is None else str(args.checkpoint),
        "base_model": None if args.base_model is None else str(args.base_model),
        "input_lighting": args.input_lighting,
    }
    result = evaluate_dataset(pipe, pairs, config, perceptual=perceptual, settings=settings)
    if args.json:
        args.json.write_text(result.to_json() + "\n")
    if args.markdown:
        args.markdown.write_text(result.to_markdown() + "\n")
    print(result.to_markdown())
    print(
        f"\n{len(pairs)} pairs in {result.seconds:.1f} s ({pipe.dtype_choice.note()}): "
        f"{result.summary()}"
    )
    return 0


def _evaluate_folders(args: argparse.Namespace) -> int:
    from gaffer_diffusion.metrics import evaluate_images

    exts = {".png", ".jpg", ".jpeg"}
    pred_names = (
        {p.name for p in args.pred.iterdir() if p.suffix.lower() in exts}
        if args.pred.is_dir()
        else set()
    )
    gt_names = (
        {p.name for p in args.gt.iterdir() if p.suffix.lower() in exts}
        if args.gt.is_dir()
        else set()
    )
    names = sorted(pred_names & gt_names)
    if not names:
        raise InputValueError(
            f"No image file names common to `--pred` {args.pred} and `--gt` {args.gt}."
        )
    if len(names) < len(gt_names):
        logger.warning("%d ground-truth images have no prediction", len(gt_names) - len(names))
    mask = _read_dir_images(args.mask_dir, names, "L") if args.mask_dir else None
    if mask is not None:  # an all-black mask leaves nothing to score (it was scored, issue 17)
        empty = [n for n, m in zip(names, mask, strict=True) if float(m.max()) <= 0.0]
        if empty:
            shown = ", ".join(empty[:5]) + (", ..." if len(empty) > 5 else "")
            raise InputValueError(
                f"`--mask-dir` {args.mask_dir}: {len(empty)} of {len(names)} masks are all black "
                f"(no object pixel to score): {shown}. Fix or remove them, or drop `--mask-dir` "
                "to score the full frames."
            )
    pred = _read_dir_images(args.pred, names, "RGB")
    gt = _read_dir_images(args.gt, names, "RGB")
    perceptual = _perceptual_arg(args)
    report = evaluate_images(pred, gt, mask=mask, names=names, perceptual=perceptual)  # type: ignore[arg-type]
    if args.json:
        args.json.write_text(report.to_json())
    if args.markdown:
        args.markdown.write_text(report.to_markdown() + "\n")
    print(report.to_markdown())
    return 0
