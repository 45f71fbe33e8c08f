"""`gaffer-diffusion insert OBJECT --into BACKGROUND --out OUT.png`: the object photo relit under the
background's lighting, placed, shadowed and composited (`gaffer_diffusion.insert`).
`_from_args.insert_request` checks every flag and file, and reads both photos, the map and the camera,
before torch is imported or weights load; the body here takes that `InsertRequest`."""

from __future__ import annotations

import argparse

from gaffer_diffusion.cli._common import _load_model, _save_png
from gaffer_diffusion.cli._from_args import SUN_SIZE_DEG as SUN_SIZE_DEG
from gaffer_diffusion.cli._from_args import _key_light as _key_light
from gaffer_diffusion.cli._from_args import insert_request
from gaffer_diffusion.cli._photo import write_with_outputs
from gaffer_diffusion.cli._requests import InsertRequest


def parse_xy(text: str) -> tuple[float, float]:
    """`--at X,Y`: two numbers (argparse type)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        x, y = (float(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not X,Y (two numbers: the pixel column and row, e.g. 320,400)"
        ) from exc
    return x, y


def parse_key_light(text: str) -> tuple[float, ...]:
    """`--key-light AZ,EL[,STRENGTH[,SIZE_DEG]]`: two to four numbers (argparse type)."""
    parts = text.split(",")
    try:
        if not 2 <= len(parts) <= 4:
            raise ValueError
        return tuple(float(p) for p in parts)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not AZ,EL[,STRENGTH[,SIZE_DEG]] (2 to 4 numbers, e.g. 135,40 or 135,40,3,5)"
        ) from exc


def _insert(args: argparse.Namespace) -> int:
    return _run_insert(insert_request(args))


def _run_insert(request: InsertRequest) -> int:
    """Insert as `request` asks; returns the exit status."""
    import time

    from gaffer_diffusion.insert import InsertConfig, insert_object
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline

    model, read, lighting, placement = (
        request.model,
        request.object,
        request.lighting,
        request.placement,
    )
    model.runtime.device_name()  # a CUDA device torch cannot use is refused before the weights load
    networks = _load_model(model.checkpoint, model.base_model)
    pipe = RelightPipeline(networks, model.runtime.runtime_config())
    compat = model.compat
    prepared = prepare_photo(read.photo, read.alpha, size=networks.config.resolution, compat=compat)
    start = time.perf_counter()
    result = insert_object(
        pipe,
        model.sampling_config(),
        prepared=prepared,
        background=request.background,
        lighting=lighting,
        placement=placement,
        config=InsertConfig(
            shadow=request.shadow, detail=request.detail, compat=compat, seed=model.seed
        ),
    )
    seconds = time.perf_counter() - start
    from gaffer_envmap.io import write_envmap

    out, save = request.out, request.save_envmap
    together = save is not None and save.absolute().parent == out.absolute().parent
    if save is not None and not together:  # another folder: written first, atomically
        save.parent.mkdir(parents=True, exist_ok=True)
        write_envmap(save, lighting.envmap)
    # the image, an estimated mask and (in the same folder) the map: all moved in, or none
    with write_with_outputs(out.parent, [read]) as stage:
        _save_png(stage / out.name, result.image)
        if together and save is not None:
            write_envmap(stage / save.name, lighting.envmap)
    light = result.light
    if request.shadow == "cycles":
        shadow = (
            "shadow: cycles (Blender's shadow catcher under the same map, "
            f"{result.proxy}; {result.shadow_seconds:.1f} s)"
        )
    elif request.shadow == "2d":
        shadow = f"shadow: 2d from {light.source} ({light.share:.0%} of the ground's light)"
    else:
        shadow = "shadow: none"
    x, y = placement.foot_xy
    notes = [
        f"object {placement.height_px:g} px tall, its lowest point at {x:g},{y:g}",
        placement.chosen,
        lighting.source,
        shadow,
        f"saved the lighting to {save}" if save is not None else "",
        read.note,
        f"{seconds:.2f} s",
    ]
    print(f"wrote {out}; " + "; ".join(n for n in (*notes, pipe.dtype_choice.note()) if n))
    return 0
