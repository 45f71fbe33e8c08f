"""`gaffer-envmap`: inspect, rotate, encode and augment environment maps from the shell.

Exit codes: 0 done; 2 refused or failed (bad input, unreadable or unwritable file: one stderr line
naming the argument and the fix); 130 interrupted (Ctrl-C); 1 only for an unexpected internal error
(a bug: Python prints its traceback). `--debug` also prints the traceback of an expected failure.
Nothing is written on failure: every output goes through an atomic write.
"""

import argparse
import glob
import json
import logging
import sys
from dataclasses import asdict
from pathlib import Path

import numpy as np

from gaffer_envmap.atomic import atomic_files
from gaffer_envmap.augment import augment_pool
from gaffer_envmap.cli_sky import add_sky_parser
from gaffer_envmap.cli_support import (
    add_debug_argument,
    check_not_an_input,
    check_output_dir,
    check_output_file,
    cli_failure,
    exit_codes_epilog,
    output_path,
)
from gaffer_envmap.compat_mode import COMPAT_MODES
from gaffer_envmap.errors import GafferEnvmapError, NonFiniteError
from gaffer_envmap.io import check_write_suffix, read_envmap, write_envmap, write_png
from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender
from gaffer_envmap.sanitize import add_sanitize_argument
from gaffer_envmap.stats import describe, total_power


def _finite_float(text: str) -> float:
    """argparse type: a finite number (NaN or Inf would rotate every pixel into NaN)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    """argparse type: an int >= 1 (0 would silently write nothing)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}")
    return value


log = logging.getLogger("gaffer_envmap")

EXIT_CODES = {
    0: "done",
    2: "refused or failed (bad input, unreadable or unwritable file; one stderr line)",
    130: "interrupted (Ctrl-C)",
    1: "an unexpected internal error (a bug; Python prints the traceback)",
}
"""What `main` returns (documented in `--help` and docs/cli.md)."""


MAX_SIZE = 8192
"""Largest `--size` accepted: an 8192 x 16384 float32 map is 1.6 GB; beyond that is a typo."""


def _map_size(text: str) -> int:
    """argparse type: a map side in [1, MAX_SIZE] (100000 would try to allocate hundreds of GB)."""
    value = _positive_int(text)
    if value > MAX_SIZE:
        raise argparse.ArgumentTypeError(f"expected at most {MAX_SIZE}, got {text!r}")
    return value


def _load_w2c(path: str) -> W2CBlender:
    try:
        arr = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise GafferEnvmapError(
            f"`--w2c` {path!r} could not be read as a .npy array: {exc}"
        ) from exc
    if not (np.issubdtype(arr.dtype, np.number) and arr.shape in ((3, 4), (4, 4))):
        raise GafferEnvmapError(
            f"`--w2c` {path!r} holds a {arr.dtype} array of shape {arr.shape}; pass a numeric 3x4 "
            "or 4x4 Blender world-to-camera matrix (np.save('w2c.npy', matrix))."
        )
    try:
        return W2CBlender.from_array(arr.astype(np.float64))
    except ValueError as exc:
        raise GafferEnvmapError(f"`--w2c` {path!r}: {exc}") from exc


def _sanitize_outcome(path: str, policy: str) -> str:
    """What reading `path` with `--sanitize policy` would do (info reports it, it refuses nothing)."""
    try:
        env = read_envmap(path, sanitize=policy)  # type: ignore[arg-type]
    except NonFiniteError:
        from gaffer_envmap.io import read_image_array
        from gaffer_envmap.sanitize import sanitize

        _, found = sanitize(read_image_array(path)[..., :3], "zero")
        return (
            f"{policy}: would refuse the map ({found.describe()}); pass --sanitize zero or clamp "
            "to repair it"
        )
    done = env.metadata.get("sanitize") if env.metadata else None
    return f"{policy}: {done}" if done else f"{policy}: clean (nothing to change)"


def _cmd_info(args: argparse.Namespace) -> int:
    env = read_envmap(args.map, sanitize="zero")  # describe() counts the raw pixels itself
    raw = None
    if args.map.lower().endswith(".exr"):
        from gaffer_envmap.io import read_image_array

        raw = read_image_array(args.map)[..., :3]
    report = asdict(describe(env, raw))
    report["sanitize"] = _sanitize_outcome(args.map, args.sanitize)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        for k, v in report.items():
            print(f"{k:26s} {v}")
    return 0


def _cmd_rotate(args: argparse.Namespace) -> int:
    check_output_file("dst", args.dst)  # outputs checked before any work: nothing half-done
    check_not_an_input("dst", args.dst, [("src", args.src), ("--w2c", args.w2c)])
    check_write_suffix(args.dst, "dst")
    env = read_envmap(args.src, sanitize=args.sanitize)
    pose = _load_w2c(args.w2c)
    from gaffer_envmap.rotate import rotate_to_camera  # torch: only once the inputs are good

    out = rotate_to_camera(
        env,
        pose,
        height=args.size,
        filter=args.filter,
        supersample=args.supersample,
        spin_deg=args.spin,
    )
    write_envmap(args.dst, out[0, 0].numpy(), dtype="float32")
    print(
        f"wrote {args.dst} ({out.shape[2]}x{out.shape[3]}, camera frame, layout neural-gaffer-camera)"
    )
    return 0


def _cmd_encode(args: argparse.Namespace) -> int:
    check_output_dir("--out-dir", args.out_dir, files=("ldr.png", "hdr.png"))
    for name in ("ldr.png", "hdr.png"):  # an LDR source map by that name would be replaced
        check_not_an_input("--out-dir", Path(args.out_dir) / name, [("src", args.src)])
    env = read_envmap(args.src, sanitize=args.sanitize)
    pose = _load_w2c(args.w2c)
    from gaffer_envmap.encode import encode_lighting  # torch: only once the inputs are good

    enc = encode_lighting(
        env, pose, size=args.size, compat=args.compat, spin_deg=args.spin, quantize=True
    )
    ldr, hdr = enc.to_uint8()
    out = Path(args.out_dir)
    # both PNGs or neither: never a new ldr.png beside an old hdr.png
    with atomic_files(out) as stage:
        write_png(stage / "ldr.png", ldr[0])
        write_png(stage / "hdr.png", hdr[0])
    print(
        f"wrote {out / 'ldr.png'} and {out / 'hdr.png'} ({args.size}x{args.size}, compat={args.compat})"
    )
    return 0


def _cmd_augment(args: argparse.Namespace) -> int:
    check_output_dir(
        "--out-dir", args.out_dir, files=(f"{glob.escape(Path(args.src).stem)}_*.exr",)
    )
    env = read_envmap(args.src, sanitize=args.sanitize)
    out = Path(args.out_dir)
    stem = Path(args.src).stem
    pool = augment_pool(env, flips=args.flips, yaw_steps=args.yaw_steps)
    with atomic_files(out) as stage:  # all maps or none: no partial output
        for spec, aug in pool:
            write_envmap(stage / f"{stem}_{spec.tag}.exr", aug)
    print(f"wrote {len(pool)} maps to {out}")
    return 0


def _cmd_procedural(args: argparse.Namespace) -> int:
    from gaffer_envmap.procedural import procedural_envmap
    from gaffer_envmap.procedural_physical import physical_envmap

    if args.count < 1 or args.first < 0:
        raise GafferEnvmapError(
            f"`--count` {args.count} and `--first` {args.first}: pass --count >= 1 and --first >= 0."
        )
    if args.height < 8:
        raise GafferEnvmapError(f"`--height` is {args.height}; pass 8 or more rows.")
    make, prefix = (
        (physical_envmap, "phys") if args.family == "physical" else (procedural_envmap, "proc")
    )
    check_output_dir("--out-dir", args.out_dir, files=(f"{prefix}_*.exr",))
    out = Path(args.out_dir)
    with atomic_files(out) as stage:  # all maps or none: no partial output
        for seed in range(args.first, args.first + args.count):
            write_envmap(stage / f"{prefix}_{seed:04d}.exr", make(seed, args.height))
    last = args.first + args.count - 1
    print(f"wrote {args.count} {args.family} maps (seeds {args.first}..{last}) to {out}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    """The embedded default job: a bundled CC0 HDRI into four camera frames, encoded both ways."""
    import time

    from gaffer_envmap.bundled import read_bundled_hdri
    from gaffer_envmap.encode import encode_lighting
    from gaffer_envmap.preview import contact_sheet, tonemap_preview
    from gaffer_envmap.rotate import rotate_to_camera

    out = Path(args.out)
    views = [f"view_{k}" for k in range(4)]
    check_output_dir(
        "--out", out, files=("world.png", "overview.png", "summary.json"), folders=views
    )
    out.mkdir(parents=True, exist_ok=True)
    env = read_bundled_hdri(args.hdri)
    poses = [orbit_w2c_blender(az, 20.0, 2.0) for az in (0.0, 90.0, 180.0, 270.0)]
    t0 = time.perf_counter()
    cam = rotate_to_camera(env, poses, height=128)[0]  # [4, 128, 256, 3]
    enc = encode_lighting(env, poses, size=args.size, quantize=True)
    t1 = time.perf_counter()
    compat = encode_lighting(env, poses, size=args.size, compat="neural-gaffer")
    t2 = time.perf_counter()
    ldr, hdr = enc.to_uint8()
    c_ldr, c_hdr = compat.to_uint8()
    exposure = 0.18 / max(
        float(np.median(env.radiance_linear @ np.array([0.2126, 0.7152, 0.0722]))), 1e-6
    )
    write_png(out / "world.png", tonemap_preview(env.radiance_linear, exposure))
    rows = [[("world map (Blender layout)", tonemap_preview(env.radiance_linear, exposure))]]
    for k, pose in enumerate(poses):
        view = out / f"view_{k}"
        view.mkdir(exist_ok=True)
        np.save(view / "w2c_blender.npy", pose.matrix)
        write_envmap(view / "camera_frame.exr", cam[k].numpy())
        for name, img in (
            ("ldr.png", ldr[k]),
            ("hdr.png", hdr[k]),
            ("compat_ldr.png", c_ldr[k]),
            ("compat_hdr.png", c_hdr[k]),
        ):
            write_png(view / name, img)
        rows.append(
            [
                (f"view {k}: camera frame", tonemap_preview(cam[k].numpy(), exposure)),
                ("E_L default", ldr[k]),
                ("E_H default", hdr[k]),
                ("E_L compat", c_ldr[k]),
                ("E_H compat", c_hdr[k]),
            ]
        )
    write_png(out / "overview.png", contact_sheet(rows, cell=160))
    summary = {
        "hdri": args.hdri,
        "source_shape": list(env.radiance_linear.shape),
        "views": len(poses),
        "encode_default_s": round(t1 - t0, 4),
        "encode_compat_s": round(t2 - t1, 4),
        "power_rgb": [float(x) for x in total_power(env)],
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(
        f"wrote {out / 'overview.png'}, {len(poses)} views under {out}/view_*/ ({json.dumps(summary)})"
    )
    return 0


def _cmd_sources(args: argparse.Namespace) -> int:
    """List the lighting sources (entry points `gaffer.envmap_sources`); a broken one is listed with
    its error, never a crash."""
    from gaffer_envmap.sources import envmap_sources, format_source_list

    entries = envmap_sources()
    if args.json:
        rows = [
            {
                "name": e.name,
                "target": e.target,
                "distribution": e.distribution,
                "capabilities": list(e.source.capabilities) if e.source else [],
                "options": list(e.source.options) if e.source else [],
                "description": e.source.description if e.source else "",
                "error": e.error,
            }
            for e in entries
        ]
        print(json.dumps(rows, indent=2))
    else:
        print(format_source_list(entries))
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for docs and tests)."""
    p = argparse.ArgumentParser(
        prog="gaffer-envmap",
        description=(__doc__ or "").splitlines()[0],
        epilog=exit_codes_epilog(EXIT_CODES),
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log INFO messages to stderr")
    sub = p.add_subparsers(dest="command", required=True)

    def add_src(sp: argparse.ArgumentParser, name: str = "src") -> None:
        sp.add_argument(name, help="environment map (.exr, .hdr, .png/.jpg), Blender convention")
        add_sanitize_argument(sp)

    sp = sub.add_parser(
        "info", help="size, range, NaN/Inf/negative counts, power, dominant light direction"
    )
    sp.add_argument("map", help="environment map (.exr, .hdr, .png/.jpg) to describe")
    sp.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_sanitize_argument(
        sp, what="reported, not applied (the `sanitize` line says what this policy would do): "
    )
    sp.set_defaults(func=_cmd_info)

    sp = sub.add_parser(
        "rotate", help="camera-frame map (layout neural-gaffer-camera) as float32 EXR"
    )
    add_src(sp)
    sp.add_argument("dst", help="output camera-frame map (.exr, float32; folders are created)")
    sp.add_argument("--w2c", required=True, help="3x4 or 4x4 Blender world-to-camera .npy")
    sp.add_argument(
        "--size",
        type=_map_size,
        default=None,
        help=f"output height (width = 2*height; at most {MAX_SIZE}); default: source",
    )
    sp.add_argument(
        "--spin",
        type=_finite_float,
        default=0.0,
        help="extra turn of the light about world up, degrees",
    )
    sp.add_argument(
        "--filter",
        choices=["conservative", "area", "bilinear"],
        default="conservative",
        help="conservative: power-exact per channel (default); area: box of bilinear sub-samples "
        "(the default before conservative, what gaffer-tiny was trained on); bilinear: one tap per "
        "pixel",
    )
    sp.add_argument(
        "--supersample",
        type=_positive_int,
        default=2,
        help="sub-samples per output pixel side (area, conservative)",
    )
    sp.set_defaults(func=_cmd_rotate)

    sp = sub.add_parser("encode", help="the model's ldr.png and hdr.png (size x size, 8-bit RGB)")
    add_src(sp)
    sp.add_argument("--w2c", required=True, help="3x4 or 4x4 Blender world-to-camera .npy")
    sp.add_argument("--out-dir", required=True, help="folder for ldr.png and hdr.png (created)")
    sp.add_argument(
        "--compat",
        choices=COMPAT_MODES,
        default="default",
        help="neural-gaffer: bit-compatible with the released checkpoint",
    )
    sp.add_argument(
        "--size",
        type=_map_size,
        default=256,
        help="side of the square maps in pixels (default: 256)",
    )
    sp.add_argument(
        "--spin",
        type=_finite_float,
        default=0.0,
        help="extra turn of the light about world up, degrees: counter-clockwise in the default "
        "mode; with --compat neural-gaffer the authors' turntable sense, D = their frame "
        "k = D / 360 * N of N (the light turns clockwise)",
    )
    sp.set_defaults(func=_cmd_encode)

    sp = sub.add_parser("augment", help="exact flips and yaw steps (the paper's pool augmentation)")
    add_src(sp)
    sp.add_argument(
        "--out-dir", required=True, help="folder for the <stem>_<tag>.exr maps (created)"
    )
    sp.add_argument("--flips", action="store_true", help="also write mirrored copies")
    sp.add_argument(
        "--yaw-steps",
        type=_positive_int,
        default=8,
        help="yaw turns per flip, evenly spaced over 360 degrees (1: no turn)",
    )
    sp.set_defaults(func=_cmd_augment)

    sp = sub.add_parser(
        "procedural",
        help="random HDR lighting maps for training data, one per seed (--family vmf or physical)",
    )
    sp.add_argument(
        "--out-dir", required=True, help="folder for the proc_<seed>.exr maps (created)"
    )
    sp.add_argument("--first", type=int, default=0, help="first seed")
    sp.add_argument(
        "--count", type=int, default=60, help="number of maps (seeds first, first+1, ...)"
    )
    sp.add_argument("--height", type=int, default=128, help="rows (width = 2 x height)")
    sp.add_argument(
        "--family",
        choices=("vmf", "physical"),
        default="vmf",
        help="'vmf' (default): sky gradients with soft emitters, proc_<seed>.exr "
        "(gaffer_envmap.procedural); 'physical': Preetham skies with a sun, overcast skies and "
        "studios, phys_<seed>.exr (gaffer_envmap.procedural_physical)",
    )
    sp.set_defaults(func=_cmd_procedural)

    add_sky_parser(sub)

    sp = sub.add_parser(
        "sources",
        help="the installed lighting sources (plugins of entry-point group gaffer.envmap_sources)",
    )
    sp.add_argument("--json", action="store_true", help="print one JSON list instead of lines")
    sp.set_defaults(func=_cmd_sources)

    sp = sub.add_parser(
        "demo", help="the embedded default: a bundled CC0 HDRI into camera frames, with pictures"
    )
    sp.add_argument(
        "--out",
        type=output_path,
        default="out/demo",
        help="output folder (created; default: out/demo)",
    )
    sp.add_argument(
        "--hdri", default="sunset", help="bundled HDRI name (city, courtyard, forest, ...)"
    )
    sp.add_argument(
        "--size",
        type=_map_size,
        default=256,
        help="side of the encoded ldr/hdr maps in pixels (default: 256)",
    )
    sp.set_defaults(func=_cmd_demo)
    add_debug_argument(p)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING, format="%(levelname)s %(message)s"
    )
    try:
        return int(args.func(args))
    except GafferEnvmapError as exc:  # with --debug (cli_failure) the traceback comes first
        return cli_failure(f"gaffer-envmap {args.command}: error: {exc}", 2, args)
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        return cli_failure(
            "interrupted (Ctrl-C): stopped; files already written are complete", 130, args
        )
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        return cli_failure(f"error: {exc}. Check the path's permissions and free space.", 2, args)


if __name__ == "__main__":
    sys.exit(main())
