"""`gaffer-diffusion prepare` and `check`: the model-ready input the model sees, and
whether the authors' release (checkpoint-80000/ and a Zero-1-to-3 XL base) is complete."""

from __future__ import annotations

import argparse
from pathlib import Path

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import _save_png
from gaffer_diffusion.cli._from_args import _check_photo_flags
from gaffer_diffusion.cli._photo import _mask_out, _photo_and_mask, write_with_outputs


def _validate_prepare(args: argparse.Namespace) -> None:
    checks.int_range("--size", args.size, 8, checks.MAX_SIDE, "the model resolution, e.g. 256")
    checks.image_size("IMAGE", args.image)
    if isinstance(args.mask, Path):
        checks.need_file("--mask", args.mask, "the object mask (white = object), or 'auto'")
    # OUT_mask.png (the model's mask) and OUT.mask.png (an estimated one) go beside it, checked
    # before any work so that nothing already written is lost
    siblings = [_model_mask_out(args.out), _mask_out(args.out)]
    checks.writable_file("--out", args.out, siblings=siblings, suffixes=(".png",))  # PNGs only
    for written in (args.out, *siblings):  # none of what it writes may replace an input
        checks.not_an_input("--out", written, [("IMAGE", args.image), ("--mask", args.mask)])


def _model_mask_out(out: Path) -> Path:
    """Where `prepare` writes the model-size mask: `OUT_mask.png`."""
    return out.with_name(f"{out.stem}_mask.png")


def _prepare(args: argparse.Namespace) -> int:
    _validate_prepare(args)
    _check_photo_flags(args)

    from gaffer_diffusion.photo import prepare_photo

    read = _photo_and_mask(None, args.image, args.mask, _mask_out(args.out))
    prepared = prepare_photo(read.photo, read.alpha, size=args.size, compat=args.compat).model_input
    mask_out = _model_mask_out(args.out)
    with write_with_outputs(args.out.parent, [read]) as stage:  # all of them or none
        _save_png(stage / args.out.name, prepared.image[0])
        _save_png(stage / mask_out.name, prepared.mask[0])
    extra = f"; {read.note}" if read.note else ""
    print(f"wrote {args.out} and {mask_out} ({args.size}x{args.size}, compat={args.compat}){extra}")
    return 0


def _check(args: argparse.Namespace) -> int:
    # no early refusal here: `check` reports missing folders in its own report (exit status 2)
    from gaffer_diffusion.release_check import check_release

    result = check_release(args.checkpoint, args.base_model)
    print(result.report())
    return 0 if result.ok else 2
