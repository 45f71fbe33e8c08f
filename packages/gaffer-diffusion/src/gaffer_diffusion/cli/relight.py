"""`gaffer-diffusion relight`: one image (optionally a turntable), or every image x every map of
folders, batched; its flag checks come first, before torch is imported or weights load."""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import (
    _ENVMAP_SUFFIXES,
    _IMAGE_SUFFIXES,
    _compat,
    _device,
    _files,
    _load_model,
    _progress,
    _runtime,
    _sampling,
    _save_png,
)
from gaffer_diffusion.cli._flag_checks import _check_model_args, _check_sampling_args
from gaffer_diffusion.cli._lighting import _check_lighting_args, _envmap_lighting, _lighting
from gaffer_diffusion.cli._photo import (
    PhotoMask,
    _check_photo_flags,
    _finish,
    _mask_out,
    _photo_and_mask,
    write_with_outputs,
)
from gaffer_diffusion.errors import (
    ConfigError,
    GafferDiffusionError,
    InputValueError,
    MissingDependencyError,
)

if TYPE_CHECKING:
    import numpy as np


def _background_note(args: argparse.Namespace) -> str:
    """The background choice, named in every relight report (issue 15, reading 5)."""
    if getattr(args, "background", "input") == "envmap":
        return "background: the target environment as the camera sees it (--background envmap)"
    if args.full_frame:
        return "background: the model's full frame (--full-frame, the authors' protocol)"
    return (
        "background: the input's, kept outside its alpha (--full-frame for the authors' full frame)"
    )


def _check_turntable_memory(args: argparse.Namespace, width: int, height: int) -> None:
    """`--turntable N` keeps N frames (and N lighting pairs) in memory: refuse what cannot fit."""
    side = (
        128 if args.checkpoint is None else 512
    )  # the model's resolution (512: the largest preset)
    out_px = side * side if args.output_size == "model" else width * height
    per_frame = 3 * 4 * out_px + 2 * 2 * 3 * side * side * 4  # frames + animation copies; E_L, E_H
    checks.fits_in_memory("--turntable", args.turntable * per_frame, f"{args.turntable} frames")


def _validate_relight(args: argparse.Namespace) -> None:
    checks.need_path(
        "IMAGE", args.image, "an object photo (its alpha, or --mask, marks the object) or a folder"
    )
    checks.int_range("--turntable", args.turntable, 0, checks.MAX_FRAMES, "e.g. 24")
    checks.finite("--fps", args.fps, 0.0, checks.MAX_FPS, lo_open=True)
    grid = args.image.is_dir() or args.envmaps is not None
    if grid and args.turntable:
        raise ConfigError(
            "`--turntable` spins one map around one image; it cannot be combined with a folder of "
            "images or `--envmaps DIR`. Relight the folder without `--turntable`."
        )
    if args.envmaps is not None and (args.envmap is not None or args.ldr is not None):
        raise ConfigError("Pass `--envmaps DIR` or `--envmap` / `--ldr --hdr`, not both.")
    _check_sampling_args(args)
    _check_lighting_args(args)
    if isinstance(args.mask, Path):
        checks.need_path("--mask", args.mask, "the object mask (white = object), or 'auto'")
    if args.sam_checkpoint is not None:
        checks.need_file("--sam-checkpoint", args.sam_checkpoint, "a Segment Anything checkpoint")
    _check_photo_flags(args)
    _check_model_args(args)
    if grid:
        # OUT/<image stem>/<map>.png and OUT/<image stem>.mask.png (issue 36: before any work)
        images = (
            _files(args.image, _IMAGE_SUFFIXES, "images", "IMAGE")
            if args.image.is_dir()
            else [args.image]
        )
        stems = [p.stem for p in images]
        checks.writable_dir(
            "--out", args.out, files=[f"{glob.escape(s)}.mask.png" for s in stems], folders=stems
        )
        checks.not_an_input("--out", args.out, [("IMAGE", args.image), ("--mask", args.mask)])
        return
    width, height = checks.image_size("IMAGE", args.image)
    stem = args.out.with_suffix("")
    siblings = [] if isinstance(args.mask, Path) else [_mask_out(args.out)]  # a mask estimate
    if args.turntable > 1:  # STEM_000.png ... and STEM.gif / STEM.mp4
        siblings += [stem.with_name(f"{stem.name}_{k:03d}.png") for k in range(args.turntable)]
        siblings += [stem.with_name(f"{stem.name}.{ext}") for ext in ("gif", "mp4")]
    checks.writable_file("--out", args.out, siblings=siblings, suffixes=(".png",))  # PNGs only
    for written in (args.out, *siblings):  # none of what it writes may replace an input
        checks.not_an_input("--out", written, [("IMAGE", args.image), ("--mask", args.mask)])
    if args.turntable > 1:
        from gaffer_diffusion._video import mp4_encoder

        if args.video == "mp4" and mp4_encoder() is None:
            raise MissingDependencyError(
                "`--video mp4` needs an MP4 encoder: an `ffmpeg` binary on PATH or PyAV "
                '(`pip install av`). Neither is installed; use `--video gif` (or "auto").'
            )
        _check_turntable_memory(args, width, height)


def _relight(args: argparse.Namespace) -> int:
    _validate_relight(args)  # every flag and file, before torch is imported or weights load
    grid = args.image.is_dir() or args.envmaps is not None
    if grid:
        return _relight_grid(args)
    # the photo and its mask are read and checked before any weights load
    stem = args.out.with_suffix("")
    read = _photo_and_mask(args, args.image, args.mask, _mask_out(args.out))
    photo, alpha, mask_note = read.photo, read.alpha, read.note
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline, relight_in_batches

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    size = model.config.resolution
    prepared = prepare_photo(photo, alpha, size=size, compat=_compat(args))
    lighting = _lighting(args, size, args.turntable)
    sampling = _sampling(args)
    n = lighting.batch_size
    frames: list[np.ndarray] = []
    model_in = prepared.model_input
    with _progress(n, "relight") as bar:
        # the same seed for every frame: the light moves, the noise does not (less flicker)
        for batch in relight_in_batches(
            pipe,
            model_in.image,
            lighting,
            sampling,
            seeds=args.seed,
            batch_size=args.batch_size,
            mask=None if args.full_frame else model_in.mask,
        ):
            for j, relit in enumerate(batch.output.images.cpu()):
                frames.append(_finish(args, prepared, relit, args.envmap, (batch.start + j, n)))
            bar.update(batch.stop - batch.start)
    notes = "; ".join(
        x
        for x in (
            _size_note(args, frames[0]),
            _background_note(args),
            mask_note,
            pipe.dtype_choice.note(),
        )
        if x
    )
    if args.turntable > 1:
        video = _write_turntable(args, stem, frames, read)
        print(f"wrote {len(frames)} frames {stem}_000.png ... and {video}; {notes}")
    else:
        with write_with_outputs(args.out.parent, [read]) as stage:  # the image and its mask
            _save_png(stage / args.out.name, frames[0])
        print(f"wrote {args.out}; {notes}")
    return 0


def _write_turntable(
    args: argparse.Namespace, stem: Path, frames: list[np.ndarray], read: PhotoMask
) -> Path:
    """`STEM_000.png ...`, the animation and an estimated mask, complete or absent (issue 17):
    written to a hidden staging folder, then moved in; an earlier run's frames of this prefix (more of
    them, or the other video format) are removed only then, so no mix of old and new frames is left."""
    from gaffer_diffusion._atomic_dir import staged_files
    from gaffer_diffusion._video import write_animation

    name = glob.escape(stem.name)
    digits = "[0-9]" * 3
    stale = [f"{name}_{digits}.png", f"{name}_{digits}[0-9].png", f"{name}.gif", f"{name}.mp4"]
    with staged_files(stem.parent, stale) as stage:
        for k, frame in enumerate(frames):
            _save_png(stage / f"{stem.name}_{k:03d}.png", frame)
        video = write_animation(
            [f[..., :3] for f in frames], stage / stem.name, fmt=args.video, fps=args.fps
        )
        read.write_mask_into(stage)
    return stem.parent / video.name


def _size_note(args: argparse.Namespace, image: np.ndarray) -> str:
    h, w = image.shape[:2]
    if args.output_size == "model":
        return f"{w}x{h}: the model's crop (--output-size model)"
    return f"{w}x{h}, the input's size, detail: {args.detail} (--output-size model for the crop)"


def _relight_grid(args: argparse.Namespace) -> int:
    """Every image x every map, batched, one progress bar: OUT/<image stem>/<map stem>.png.

    Each output is written atomically; an image that cannot be read or relit is reported and the
    others go on (exit status 1 when any failed)."""
    folder = args.image.is_dir()
    images = _files(args.image, _IMAGE_SUFFIXES, "images", "IMAGE") if folder else [args.image]
    if isinstance(args.mask, Path) and folder and not args.mask.is_dir():
        raise ConfigError(
            "With a folder of images, `--mask` must be a folder of masks too (or 'auto')."
        )
    failed: list[str] = []
    loaded: list[tuple[Path, PhotoMask]] = []
    notes: list[str] = []
    for path in images:
        mask = (
            args.mask / path.name
            if isinstance(args.mask, Path) and args.mask.is_dir()
            else args.mask
        )
        try:
            read = _photo_and_mask(args, path, mask, args.out / f"{path.stem}.mask.png")
        except GafferDiffusionError as exc:
            if not folder:
                raise
            failed.append(f"{path.name}: {exc}")
            continue
        loaded.append((path, read))
        notes += [read.note] if read.note else []
    if not loaded:
        raise InputValueError(f"None of the {len(images)} images could be used; {failed[0]}")
    import torch

    from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline, relight_built_batches

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    size = model.config.resolution
    prepared = [prepare_photo(r.photo, r.alpha, size=size, compat=_compat(args)) for _, r in loaded]
    if args.envmaps is not None:
        maps = _files(args.envmaps, _ENVMAP_SUFFIXES, "environment maps", "--envmaps")
        lights = [(m.stem, m, _envmap_lighting(args, m, size)) for m in maps]
    else:
        label = args.envmap.stem if args.envmap is not None else args.ldr.stem
        lights = [(label, args.envmap, _lighting(args, size, 0))]
    jobs = [(i, e) for i in range(len(loaded)) for e in range(len(lights))]
    sampling = _sampling(args)
    args.out.mkdir(parents=True, exist_ok=True)
    written = 0
    masked: set[int] = set()

    def build(lo: int, hi: int) -> RelightingConditions:
        chunk = jobs[lo:hi]
        return RelightingConditions(
            image=torch.cat([prepared[i].model_input.image for i, _ in chunk]),
            mask=None
            if args.full_frame
            else torch.cat([prepared[i].model_input.mask for i, _ in chunk]),
            lighting=LightingMaps(
                ldr=torch.cat([lights[e][2].ldr for _, e in chunk]),
                hdr=torch.cat([lights[e][2].hdr for _, e in chunk]),
            ),
        )

    with _progress(len(jobs), "relight") as bar:
        # one seed for every item: a result does not depend on the batch it landed in
        for batch in relight_built_batches(
            pipe, len(jobs), build, sampling, seeds=args.seed, batch_size=args.batch_size
        ):
            chunk = jobs[batch.start : batch.stop]
            for (i, e), image in zip(chunk, batch.output.images.cpu(), strict=True):
                dest = args.out / loaded[i][0].stem / f"{lights[e][0]}.png"
                try:
                    _save_png(dest, _finish(args, prepared[i], image, lights[e][1]))
                    written += 1
                    if i not in masked:  # an estimated mask goes with its image's first output
                        loaded[i][1].write_mask_into(args.out)
                        masked.add(i)
                except (GafferDiffusionError, OSError, ValueError) as exc:
                    failed.append(f"{dest}: {exc}")
            bar.update(len(chunk))
    print(
        f"wrote {written} images ({len(loaded)} inputs x {len(lights)} maps) under {args.out}; "
        f"{_background_note(args)}; {pipe.dtype_choice.note()}"
        + "".join(f"; {n}" for n in notes[:1])
    )
    if failed:
        print(f"error: {len(failed)} failed (the others were written):", file=sys.stderr)
        for line in failed:
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0
