"""`gaffer-diffusion insert OBJECT --into BACKGROUND --out OUT.png` (issue 32): the object photo
relit under the background's lighting, placed, shadowed and composited (`gaffer_diffusion.insert`).
Every flag and file is checked, and both photos read, before torch is imported or weights load."""

from __future__ import annotations

import argparse
import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import (
    _compat,
    _device,
    _load_model,
    _runtime,
    _sampling,
    _save_png,
)
from gaffer_diffusion.cli._flag_checks import _check_model_args, _check_sampling_args
from gaffer_diffusion.cli._lighting import _check_envmap_arg, _read_envmap, _read_w2c
from gaffer_diffusion.cli._photo import (
    PhotoMask,
    _check_photo_flags,
    _mask_out,
    _photo_and_mask,
    write_with_outputs,
)
from gaffer_diffusion.errors import ConfigError, InputValueError, MissingDependencyError

if TYPE_CHECKING:
    from gaffer_diffusion.insert_geometry import InsertLighting, KeyLight, Placement
    from gaffer_diffusion.photo import Photo


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


@dataclass(frozen=True, kw_only=True)
class _Checked:
    """What the checks read: the background's size, the map of `--envmap`, the key light and the
    lighting source of `--light-source` with its options."""

    background_wh: tuple[int, int]
    envmap: Any  # gaffer_envmap.EnvironmentMap | None
    w2c: Any  # gaffer_envmap.poses.W2CBlender
    key_light: KeyLight | None
    light_source: Any = None  # gaffer_envmap.sources.EnvmapSource | None (--light-source)
    light_options: dict[str, str] | None = None


SUN_SIZE_DEG = 0.53
"""The sun's angular diameter, degrees: the size of a `--sun-at` key light."""


def _key_light(args: argparse.Namespace) -> KeyLight | None:
    """`--key-light`, or the sun of `--sun-at` seen from a camera looking along `--camera-heading`."""
    from gaffer_diffusion.insert_geometry import KeyLight

    sun_at = getattr(args, "sun_at", None)
    heading = getattr(args, "camera_heading", None)
    if sun_at is None:
        if heading is not None:
            raise ConfigError("`--camera-heading` goes with `--sun-at LAT,LON,TIME`; pass both.")
        if args.key_light is None:
            return None
        names = ("azimuth_deg", "elevation_deg", "strength", "size_deg")
        return KeyLight(**dict(zip(names, args.key_light, strict=False)))
    if args.key_light is not None:
        raise ConfigError("Pass `--key-light` or `--sun-at`, not both (both place the key light).")
    if heading is None or args.w2c is not None:
        raise ConfigError(
            "`--sun-at` needs `--camera-heading DEG` (the compass bearing the background camera "
            "looks along), and no `--w2c`."
        )
    checks.finite("--camera-heading", heading)
    from gaffer_envmap.sun_position import parse_place, parse_time, sun_position_at

    parts = sun_at.split(",", 2)
    if len(parts) != 3:
        raise ConfigError(
            f"`--sun-at` {sun_at!r} is not LAT,LON,TIME; e.g. 48.86,2.29,2026-06-21T17:00+02:00."
        )
    lat, lon = parse_place(",".join(parts[:2]), "--sun-at")
    sun = sun_position_at(lat, lon, parse_time(parts[2], "--sun-at"))
    if sun.elevation_deg <= 0:
        raise InputValueError(
            f"`--sun-at` {sun_at}: the sun is {-sun.elevation_deg:.1f} degrees below the horizon "
            "then; pass a daytime, or place the light with `--key-light AZ,EL`."
        )
    # the default camera looks along world +y: the sun's bearing relative to the camera's
    return KeyLight(
        azimuth_deg=(sun.azimuth_deg - heading) % 360.0,
        elevation_deg=sun.elevation_deg,
        size_deg=SUN_SIZE_DEG,
    )


def _shown_size(flag: str, path: Path) -> tuple[int, int]:
    """(width, height) of an image as displayed (EXIF orientation 5 to 8 swaps them, as `read_photo`
    and `read_mask` apply it), from its header."""
    w, h = checks.image_size(flag, path)
    from PIL import Image

    try:
        with Image.open(path) as im:
            turned = im.getexif().get(0x0112, 1) in (5, 6, 7, 8)
    except (OSError, ValueError, SyntaxError):
        turned = False
    return (h, w) if turned else (w, h)


def _check_shadow(mode: str) -> None:
    if mode != "cycles":
        return
    if importlib.util.find_spec("bpy") is None:
        raise MissingDependencyError(
            "`--shadow cycles` needs Blender's Python module bpy (pip install "
            '"gaffer-data[render]"), which is not installed; use `--shadow 2d` (the pixel-height '
            "shadow, the default)."
        )


def _check_light_source(args: argparse.Namespace) -> tuple[Any, dict[str, str]] | None:
    """`--light-source NAME` (a plugin, `gaffer_envmap.sources`): loaded, its capability and options
    checked, and the other lighting flags refused beside it."""
    if args.light_source is None:
        for flag, value in (
            ("--light-text", args.light_text),
            ("--light-source-option", args.light_source_option),
        ):
            if value:
                raise ConfigError(f"`{flag}` goes with `--light-source NAME`; pass both.")
        return None
    for flag, given in (
        ("--envmap", args.envmap is not None),
        ("--light-from-photo", args.light_from_photo),
        ("--key-light", args.key_light is not None),
        ("--sun-at", args.sun_at is not None),
    ):
        if given:
            raise ConfigError(
                f"`--light-source` {args.light_source!r} makes the whole lighting; drop `{flag}` "
                "(or drop --light-source)."
            )
    from gaffer_envmap.sources import load_envmap_source, parse_source_options

    source = load_envmap_source(args.light_source, flag="--light-source")
    if args.light_text is not None and "text" not in source.capabilities:
        raise ConfigError(
            f"`--light-source` {source.name!r} reads the background photo, not words; drop "
            "`--light-text`."
        )
    if args.light_text is None and "photo" not in source.capabilities:
        raise ConfigError(
            f"`--light-source` {source.name!r} turns words into lighting; pass `--light-text "
            'PHRASE` (e.g. "golden hour from the left").'
        )
    if args.light_text is None and args.w2c is not None:
        raise ConfigError(
            f"`--w2c`: the map `--light-source` {source.name!r} estimates from the photo is in the "
            "background camera's own frame; drop --w2c."
        )
    return source, parse_source_options(
        args.light_source_option, source, flag="--light-source-option"
    )


def _validate_insert(args: argparse.Namespace) -> _Checked:
    """Every flag and file, before torch is imported or a model loads; one line per refusal."""
    from gaffer_envmap.poses import W2CBlender

    ow, oh = _shown_size("OBJECT", args.object)
    bw, bh = _shown_size("--into", args.into)
    if isinstance(args.mask, Path):
        mw, mh = _shown_size("--mask", args.mask)
        if (mw, mh) != (ow, oh):
            raise InputValueError(
                f"`--mask` {args.mask} is {mw}x{mh} but OBJECT {args.object} is {ow}x{oh} (width x "
                "height); pass the object photo's mask, of its size (white = object), or "
                "`--mask auto`."
            )
    _check_photo_flags(args)
    checks.finite("--fov", args.fov, 1.0, 179.0)
    if args.height is not None:
        checks.finite("--height", args.height, 0.0, lo_open=True)
    if args.at is not None:
        x, y = args.at
        if not (math.isfinite(x) and math.isfinite(y) and 0 <= x < bw and 0 <= y < bh):
            raise InputValueError(
                f"`--at` {x:g},{y:g} is outside the background ({bw}x{bh}): pass X in "
                f"[0, {bw - 1}] and Y in [0, {bh - 1}], pixels from the top-left."
            )
    _check_shadow(args.shadow)
    if args.envmap is not None and args.light_from_photo:
        raise ConfigError(
            "Pass `--envmap` (a map you have) or `--light-from-photo` (the map built from the "
            "background), not both."
        )
    if args.envmap is not None and (args.key_light is not None or args.sun_at is not None):
        flag = "--key-light" if args.key_light is not None else "--sun-at"
        raise ConfigError(
            f"`{flag}` adds a key light to the map built from the background "
            "(`--light-from-photo`); an `--envmap` brings its own light. Drop one of them."
        )
    envmap = None
    if args.envmap is not None:
        _check_envmap_arg(args.envmap)
        envmap = _read_envmap(args, args.envmap)  # decoded now: an unreadable map fails here
    w2c = W2CBlender.from_array(_read_w2c(args.w2c)) if args.w2c is not None else None
    light_source = _check_light_source(args)
    key = _key_light(args)
    _check_sampling_args(args)
    _check_model_args(args)
    inputs = [
        ("OBJECT", args.object),
        ("--into", args.into),
        ("--mask", args.mask),
        ("--envmap", args.envmap),
        ("--w2c", args.w2c),
    ]
    siblings = [] if isinstance(args.mask, Path) else [_mask_out(args.out)]
    checks.writable_file("--out", args.out, siblings=siblings, suffixes=(".png",))
    checks.not_an_input("--out", args.out, inputs)
    if args.save_envmap is not None:
        from gaffer_envmap.io import check_write_suffix

        check_write_suffix(args.save_envmap, "--save-envmap")
        checks.writable_file("--save-envmap", args.save_envmap)
        checks.not_an_input("--save-envmap", args.save_envmap, [*inputs, ("--out", args.out)])
    return _Checked(
        background_wh=(bw, bh),
        envmap=envmap,
        w2c=w2c,
        key_light=key,
        light_source=light_source[0] if light_source else None,
        light_options=light_source[1] if light_source else None,
    )


def _lighting_for(args: argparse.Namespace, checked: _Checked, background: Photo) -> InsertLighting:
    from gaffer_diffusion.insert_geometry import (
        LEVEL_CAMERA,
        BackgroundCamera,
        InsertLighting,
        light_from_photo,
    )

    w, h = background.size_wh
    camera = BackgroundCamera(
        width=w, height=h, fov_deg=args.fov, w2c=checked.w2c if checked.w2c else LEVEL_CAMERA
    )
    if checked.envmap is not None:
        return InsertLighting(
            envmap=checked.envmap, camera=camera, source=f"lighting: --envmap {args.envmap}"
        )
    if checked.light_source is not None:
        return _lighting_from_source(args, checked, background, camera)
    key = checked.key_light
    source = "lighting: the background wrapped onto the sphere (--light-from-photo) + " + (
        f"{'the sun of --sun-at' if args.sun_at else 'a key light'} at azimuth "
        f"{key.azimuth_deg:.1f}, elevation {key.elevation_deg:.1f}, strength {key.strength:g}, "
        f"{key.size_deg:g} degrees"
        if key is not None
        else "no key light: the photo rarely shows its key light; give it with `--key-light AZ,EL`"
    )
    env = light_from_photo(background.rgb, camera, key)
    return InsertLighting(envmap=env, camera=camera, key_light=key, source=source)


def _lighting_from_source(
    args: argparse.Namespace, checked: _Checked, background: Photo, camera: Any
) -> InsertLighting:
    """The map of `--light-source`: from `--light-text`, or estimated from the background photo."""
    from gaffer_diffusion.insert_geometry import LIGHT_FROM_PHOTO_WIDTH, InsertLighting
    from gaffer_envmap.sources import envmap_from_photo, envmap_from_text

    source = checked.light_source
    common = {
        "width": LIGHT_FROM_PHOTO_WIDTH,
        "options": checked.light_options,
        "policy": args.sanitize,
        "flag": "--light-source",
    }
    if args.light_text is not None:
        env = envmap_from_text(source, args.light_text, **common)
        what = f"--light-text {args.light_text!r}"
    else:
        env = envmap_from_photo(source, background.rgb, fov_deg=args.fov, **common)
        what = f"the background photo at --fov {args.fov:g}"
    note = env.metadata.get("gaffer:source_note")
    return InsertLighting(
        envmap=env,
        camera=camera,
        source=f"lighting: --light-source {source.name} from {what}"
        + (f" ({note})" if note else ""),
    )


def _placement(args: argparse.Namespace, read: PhotoMask, background: Photo) -> Placement:
    from gaffer_diffusion.insert_geometry import object_extent, resolve_placement

    return resolve_placement(
        background.size_wh, object_extent(read.alpha), at_xy=args.at, height_px=args.height
    )


def _insert(args: argparse.Namespace) -> int:
    import time

    checked = _validate_insert(args)  # every flag and file, before torch or weights
    read = _photo_and_mask(args, args.object, args.mask, _mask_out(args.out))
    from gaffer_diffusion.photo import read_photo

    background = read_photo(args.into)
    placement = _placement(args, read, background)  # --at / --height refused before weights
    lighting = _lighting_for(args, checked, background)
    from gaffer_diffusion.insert import InsertConfig, insert_object
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    compat = _compat(args)
    prepared = prepare_photo(read.photo, read.alpha, size=model.config.resolution, compat=compat)
    start = time.perf_counter()
    result = insert_object(
        pipe,
        _sampling(args),
        prepared=prepared,
        background=background,
        lighting=lighting,
        placement=placement,
        config=InsertConfig(shadow=args.shadow, detail=args.detail, compat=compat, seed=args.seed),
    )
    seconds = time.perf_counter() - start
    from gaffer_envmap.io import write_envmap

    save = args.save_envmap
    together = save is not None and save.absolute().parent == args.out.absolute().parent
    if save is not None and not together:  # another folder: written first, atomically
        save.parent.mkdir(parents=True, exist_ok=True)
        write_envmap(save, lighting.envmap)
    # the image, an estimated mask and (in the same folder) the map: all moved in, or none
    with write_with_outputs(args.out.parent, [read]) as stage:
        _save_png(stage / args.out.name, result.image)
        if together and save is not None:
            write_envmap(stage / save.name, lighting.envmap)
    light = result.light
    if args.shadow == "cycles":
        shadow = (
            "shadow: cycles (Blender's shadow catcher under the same map, a proxy inflated from the "
            f"mask; {result.shadow_seconds:.1f} s)"
        )
    elif args.shadow == "2d":
        shadow = f"shadow: 2d from {light.source} ({light.share:.0%} of the ground's light)"
    else:
        shadow = "shadow: none"
    x, y = placement.foot_xy
    notes = [
        f"object {placement.height_px:g} px tall, its lowest point at {x:g},{y:g}",
        placement.chosen,
        lighting.source,
        shadow,
        f"saved the lighting to {args.save_envmap}" if args.save_envmap is not None else "",
        read.note,
        f"{seconds:.2f} s",
    ]
    print(f"wrote {args.out}; " + "; ".join(n for n in (*notes, pipe.dtype_choice.note()) if n))
    return 0
