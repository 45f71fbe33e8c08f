"""`gaffer-diffusion normals` and `train-normals`: the learned normal estimator alone, and
training it on gaffer-data renders (extra [train])."""

from __future__ import annotations

import argparse
from pathlib import Path

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import _save_png
from gaffer_diffusion.cli._from_args import _check_photo_flags
from gaffer_diffusion.cli._photo import _mask_out, _photo_and_mask, write_with_outputs
from gaffer_diffusion.errors import ConfigError


def _validate_normals(args: argparse.Namespace) -> None:
    checks.image_size("IMAGE", args.image)
    if isinstance(args.mask, Path):
        checks.need_file("--mask", args.mask, "the object mask (white = object), or 'auto'")
    if args.estimator is not None:
        checks.need_dir("--estimator", args.estimator, "a folder written by `train-normals`")
    # an estimated mask goes beside it, as OUT.mask.png: checked before any work
    siblings = [] if isinstance(args.mask, Path) else [_mask_out(args.out)]
    checks.writable_file("--out", args.out, siblings=siblings)
    for written in (args.out, *siblings):  # none of what it writes may replace an input
        checks.not_an_input("--out", written, [("IMAGE", args.image), ("--mask", args.mask)])
    if args.out.suffix.lower() != ".png":
        raise ConfigError(f"`--out` is {str(args.out)!r}; expected a .png file.")


def _normals(args: argparse.Namespace) -> int:
    """Camera-frame normals of a photo's object, as a PNG (RGB = (n + 1) / 2, x right, y up, z toward
    the camera; white outside the mask) at the model's framing, or pasted back at the photo's size."""
    _validate_normals(args)
    _check_photo_flags(args)
    import torch
    import torch.nn.functional as F

    from gaffer_diffusion.geometry.estimator import (
        estimate_normals,
        load_normal_estimator,
        shipped_normal_estimator,
    )
    from gaffer_diffusion.photo import prepare_photo

    read = _photo_and_mask(None, args.image, args.mask, _mask_out(args.out))
    photo, alpha, note = read.photo, read.alpha, read.note
    est = (
        shipped_normal_estimator()
        if args.estimator is None
        else load_normal_estimator(args.estimator)
    )
    size = est.config.resolution
    prepared = prepare_photo(photo, alpha, size=size)
    inp = prepared.model_input
    normals = estimate_normals(est, inp.image.float(), inp.mask.float())  # [1, 3, S, S]
    if args.output_size == "input":
        fr = prepared.framing
        h, w = alpha.shape
        # the square's pixels back into the photo: sample the normals at each photo pixel
        ys = (torch.arange(h, dtype=torch.float32) + 0.5 - fr.top) / fr.side_y * 2 - 1
        xs = (torch.arange(w, dtype=torch.float32) + 0.5 - fr.left) / fr.side_x * 2 - 1
        grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), dim=-1)[None]
        full = F.grid_sample(normals, grid, mode="bilinear", align_corners=False)[0]
        full = full / full.norm(dim=0, keepdim=True).clamp_min(1e-6)
        m = torch.from_numpy(alpha > 0.5)[None]
        enc = torch.where(m, (full + 1) / 2, torch.ones_like(full))
    else:
        m = inp.mask[0] > 0.5
        enc = torch.where(m, (normals[0] + 1) / 2, torch.ones_like(normals[0]))
    with write_with_outputs(args.out.parent, [read]) as stage:  # the normals and their mask
        _save_png(stage / args.out.name, enc)
    extra = f"; {note}" if note else ""
    print(f"wrote {args.out} (camera-frame normals, RGB = (n + 1) / 2){extra}")
    return 0


ESTIMATOR_MARK = "gaffer_normals.json"
"""`geometry.estimator.ESTIMATOR_CONFIG_NAME`, named here without importing torch (a test keeps the two
equal): the file that marks an estimator folder."""


def _check_replaceable_estimator(args: argparse.Namespace) -> None:
    """The new estimator replaces the whole `--out` folder (`atomic_dir`): refuse one that holds
    anything but an earlier estimator, and one that is or holds `--data` / `--val` (so that
    nothing already written is lost)."""
    out = args.out.absolute().resolve()
    for flag, src in [*(("--data", d) for d in args.data), ("--val", args.val)]:
        if src is not None and (
            out == src.absolute().resolve() or out in src.absolute().resolve().parents
        ):
            raise ConfigError(
                f"`--out` {args.out} is or holds `{flag}` {src}, and the estimator replaces the "
                "whole folder; pass a new folder."
            )
    if out.is_dir() and any(out.iterdir()) and not (out / ESTIMATOR_MARK).is_file():
        raise ConfigError(
            f"`--out` {args.out} holds files that are not a normal estimator's (no "
            f"{ESTIMATOR_MARK}), and the estimator replaces the whole folder; pass a new "
            "folder, or an earlier estimator's to replace it."
        )


def _train_normals(args: argparse.Namespace) -> int:
    for data in args.data:
        checks.need_dir("--data", data, "a gaffer-data render folder (with normal passes)")
    if args.init is not None:
        checks.need_dir("--init", args.init, "an estimator folder (gaffer_normals.json, unet/)")
    widths = checks.channel_widths("--widths", args.widths)
    if widths is not None and args.init is not None:
        raise ConfigError(
            "`--widths` sets the shapes of a new estimator, `--init` keeps those of the one it "
            "continues: pass one of them."
        )
    checks.finite("--lr", args.lr, lo=1e-7, hi=1.0)
    if args.val is not None:
        checks.need_dir("--val", args.val, "a gaffer-data render folder (with normal passes)")
    checks.replaceable_dir("--out", args.out)
    _check_replaceable_estimator(args)
    checks.finite("--minutes", args.minutes, lo=0.1, hi=24 * 60.0)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    checks.int_range("--steps", args.steps, 1, 10_000_000)
    from gaffer_diffusion.cli.train import _training_module

    _training_module("train-normals")
    import json
    import logging
    import time

    from gaffer_diffusion._atomic_dir import atomic_dir
    from gaffer_diffusion.geometry.estimator import NormalEstimatorConfig, load_normal_estimator
    from gaffer_diffusion.training.normals import (
        NormalTrainConfig,
        angular_errors,
        concat_views,
        load_geometry_views,
        train_normal_estimator,
    )

    logging.basicConfig(level=logging.INFO, format="%(message)s")
    t0 = time.perf_counter()
    init = None if args.init is None else load_normal_estimator(args.init)
    train = concat_views([load_geometry_views(data) for data in args.data])
    print(f"read {train.images.shape[0]} training views in {time.perf_counter() - t0:.0f} s")
    if init is not None:
        shapes = init.config  # continuing keeps the estimator's shapes
    elif widths is not None:
        shapes = NormalEstimatorConfig(block_out_channels=widths)
    else:
        shapes = NormalEstimatorConfig()
    config = NormalTrainConfig(
        estimator=shapes,
        max_seconds=args.minutes * 60.0,
        max_steps=args.steps,
        lr=args.lr,
        seed=args.seed,
        threads=args.threads,
    )
    est, stats = train_normal_estimator(train, config, init=init)
    data = str(args.data[0]) if len(args.data) == 1 else [str(d) for d in args.data]
    training: dict[str, object] = {
        **stats,
        "data": data,
        "seed": args.seed,
        "max_steps": args.steps,
        "lr": args.lr,
    }
    if args.init is not None:
        training["init"] = str(args.init)
    extra: dict[str, object] = {"training": training}
    if args.val is not None:
        errors = angular_errors(est, load_geometry_views(args.val))
        extra["validation"] = {
            "data": str(args.val),
            "views": errors.views,
            "mean_angular_error_deg": round(errors.estimated_deg, 3),
            "silhouette_dome_mean_angular_error_deg": round(errors.silhouette_dome_deg, 3),
        }
        print(
            f"validation: mean angular error {errors.estimated_deg:.2f} deg "
            f"(silhouette dome {errors.silhouette_dome_deg:.2f} deg) on {errors.views} views"
        )
    with atomic_dir(args.out) as stage:
        est.save(stage, extra=extra)
    print(
        f"wrote {args.out} ({int(stats['steps'])} steps, {stats['seconds']:.0f} s); "
        f"{json.dumps(extra.get('validation', {}))}"
    )
    return 0
