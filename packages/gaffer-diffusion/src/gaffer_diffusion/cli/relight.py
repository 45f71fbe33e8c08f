"""`gaffer-diffusion relight`: one image (optionally a turntable), or every image x every map of
folders, batched. `_from_args.relight_request` checks every flag and reads every input first, before
torch is imported or weights load; the bodies here take that `RelightRequest`."""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion.cli._common import _load_model, _progress, _save_png
from gaffer_diffusion.cli._from_args import relight_request
from gaffer_diffusion.cli._photo import _finish, write_with_outputs
from gaffer_diffusion.cli._requests import OutputLook, PhotoMask, RelightRequest
from gaffer_diffusion.errors import GafferDiffusionError

if TYPE_CHECKING:
    import numpy as np

    from gaffer_diffusion.pipelines import RelightPipeline


def _background_note(look: OutputLook, full_frame: bool) -> str:
    """The background choice, named in every relight report."""
    if look.background == "envmap":
        return "background: the target environment as the camera sees it (--background envmap)"
    if full_frame:
        return "background: the model's full frame (--full-frame, the authors' protocol)"
    return (
        "background: the input's, kept outside its alpha (--full-frame for the authors' full frame)"
    )


def _relight(args: argparse.Namespace) -> int:
    return _run_relight(relight_request(args))


def _pipeline(request: RelightRequest) -> RelightPipeline:
    from gaffer_diffusion.pipelines import RelightPipeline

    model = request.model
    model.runtime.device_name()  # a CUDA device torch cannot use is refused before the weights load
    return RelightPipeline(
        _load_model(model.checkpoint, model.base_model), model.runtime.runtime_config()
    )


def _run_relight(request: RelightRequest) -> int:
    """Relight as `request` asks; returns the exit status (1: some images of a folder failed)."""
    if request.grid:
        return _relight_grid(request)
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import relight_in_batches

    (_, read), light, model = request.photos[0], request.lights[0], request.model
    pipe = _pipeline(request)
    size = pipe.model.config.resolution
    prepared = prepare_photo(read.photo, read.alpha, size=size, compat=model.compat)
    lighting = light.maps(size, model.compat, request.turntable)
    n = lighting.batch_size
    frames: list[np.ndarray] = []
    model_in = prepared.model_input
    with _progress(n, "relight") as bar:
        # the same seed for every frame: the light moves, the noise does not (less flicker)
        for batch in relight_in_batches(
            pipe,
            model_in.image,
            lighting,
            model.sampling_config(),
            seeds=model.seed,
            batch_size=model.batch_size,
            mask=None if model.full_frame else model_in.mask,
        ):
            for j, relit in enumerate(batch.output.images.cpu()):
                frames.append(_finish(request.look, prepared, relit, light, (batch.start + j, n)))
            bar.update(batch.stop - batch.start)
    notes = "; ".join(
        x
        for x in (
            _size_note(request.look, frames[0]),
            _background_note(request.look, model.full_frame),
            read.note,
            pipe.dtype_choice.note(),
        )
        if x
    )
    out = request.out
    stem = out.with_suffix("")
    if request.turntable > 1:
        video = _write_turntable(request, stem, frames, read)
        print(f"wrote {len(frames)} frames {stem}_000.png ... and {video}; {notes}")
    else:
        with write_with_outputs(out.parent, [read]) as stage:  # the image and its mask
            _save_png(stage / out.name, frames[0])
        print(f"wrote {out}; {notes}")
    return 0


def _write_turntable(
    request: RelightRequest, stem: Path, frames: list[np.ndarray], read: PhotoMask
) -> Path:
    """`STEM_000.png ...`, the animation and an estimated mask, complete or absent: written to a
    hidden staging folder, then moved in; an earlier run's frames of this prefix (more of them, or the
    other video format) are removed only then, so no mix of old and new frames is left."""
    from gaffer_diffusion._atomic_dir import staged_files
    from gaffer_diffusion._video import write_animation

    name = glob.escape(stem.name)
    digits = "[0-9]" * 3
    stale = [f"{name}_{digits}.png", f"{name}_{digits}[0-9].png", f"{name}.gif", f"{name}.mp4"]
    with staged_files(stem.parent, stale) as stage:
        for k, frame in enumerate(frames):
            _save_png(stage / f"{stem.name}_{k:03d}.png", frame)
        video = write_animation(
            [f[..., :3] for f in frames],
            stage / stem.name,
            fmt=request.video,  # type: ignore[arg-type]
            fps=request.fps,
        )
        read.write_mask_into(stage)
    return stem.parent / video.name


def _size_note(look: OutputLook, image: np.ndarray) -> str:
    h, w = image.shape[:2]
    if look.output_size == "model":
        return f"{w}x{h}: the model's crop (--output-size model)"
    return f"{w}x{h}, the input's size, detail: {look.detail} (--output-size model for the crop)"


def _relight_grid(request: RelightRequest) -> int:
    """Every image x every map, batched, one progress bar: OUT/<image stem>/<map stem>.png.

    Each output is written atomically; an image that cannot be read or relit is reported and the
    others go on (exit status 1 when any failed)."""
    import torch

    from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import relight_built_batches

    model, out, loaded = request.model, request.out, request.photos
    failed = list(request.unreadable)
    notes = [read.note for _, read in loaded if read.note]
    pipe = _pipeline(request)
    size = pipe.model.config.resolution
    prepared = [prepare_photo(r.photo, r.alpha, size=size, compat=model.compat) for _, r in loaded]
    lights = [(light, light.maps(size, model.compat)) for light in request.lights]
    jobs = [(i, e) for i in range(len(loaded)) for e in range(len(lights))]
    out.mkdir(parents=True, exist_ok=True)
    written = 0
    masked: set[int] = set()

    def build(lo: int, hi: int) -> RelightingConditions:
        chunk = jobs[lo:hi]
        return RelightingConditions(
            image=torch.cat([prepared[i].model_input.image for i, _ in chunk]),
            mask=None
            if model.full_frame
            else torch.cat([prepared[i].model_input.mask for i, _ in chunk]),
            lighting=LightingMaps(
                ldr=torch.cat([lights[e][1].ldr for _, e in chunk]),
                hdr=torch.cat([lights[e][1].hdr for _, e in chunk]),
            ),
        )

    with _progress(len(jobs), "relight") as bar:
        # one seed for every item: a result does not depend on the batch it landed in
        for batch in relight_built_batches(
            pipe,
            len(jobs),
            build,
            model.sampling_config(),
            seeds=model.seed,
            batch_size=model.batch_size,
        ):
            chunk = jobs[batch.start : batch.stop]
            for (i, e), image in zip(chunk, batch.output.images.cpu(), strict=True):
                light = lights[e][0]
                dest = out / loaded[i][0].stem / f"{light.label}.png"
                try:
                    _save_png(dest, _finish(request.look, prepared[i], image, light))
                    written += 1
                    if i not in masked:  # an estimated mask goes with its image's first output
                        loaded[i][1].write_mask_into(out)
                        masked.add(i)
                except (GafferDiffusionError, OSError, ValueError) as exc:
                    failed.append(f"{dest}: {exc}")
            bar.update(len(chunk))
    print(
        f"wrote {written} images ({len(loaded)} inputs x {len(lights)} maps) under {out}; "
        f"{_background_note(request.look, model.full_frame)}; {pipe.dtype_choice.note()}"
        + "".join(f"; {n}" for n in notes[:1])
    )
    if failed:
        print(f"error: {len(failed)} failed (the others were written):", file=sys.stderr)
        for line in failed:
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0
