"""`gaffer-envmap sky`: a physical sky (or a studio) as an HDR lat-long EXR, from angles, a place and
a time, or words.

With `--source NAME` the words go to a lighting source instead (`gaffer_envmap.sources`: an installed
plugin's text-to-HDR model, or the built-in grammar registered as "sky"); `--list-sources` lists them.

The sun's position comes from, in this order: `--sun-elevation` / `--sun-azimuth`; `--at` / `--time`
(an ephemeris, `gaffer_envmap.sun_position`); the time of day and direction in `--text`; else the
phrase grammar's default sun. Every argument is checked before anything is computed, and the map is
written atomically, so a refusal leaves nothing behind.
"""

import argparse
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gaffer_envmap.cli_support import check_output_file
from gaffer_envmap.errors import GafferEnvmapError, ParameterError
from gaffer_envmap.sky import (
    DEFAULT_EXPOSURE_EV,
    DEFAULT_GROUND_ALBEDO,
    DEFAULT_TURBIDITY,
    SKY_MODELS,
    TURBIDITY_RANGE,
    SkyConfig,
    SunPosition,
)
from gaffer_envmap.studio import StudioConfig

__all__ = ["ListSourcesAction", "add_sky_parser", "cmd_sky"]

MAX_WIDTH = 16384
"""Largest `--width`: a 16384 x 8192 float32 map is 1.6 GB; beyond that is a typo."""


def _number_in(lo: float | int, hi: float | int) -> Callable[[str], float]:
    """An argparse type: a finite number in [lo, hi]."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        if not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"expected a number in [{lo:g}, {hi:g}], got {text!r}")
        return value

    return parse


def _width(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an even integer, got {text!r}") from None
    if value % 2 or not 8 <= value <= MAX_WIDTH:
        raise argparse.ArgumentTypeError(
            f"expected an even integer in [8, {MAX_WIDTH}] (height = width / 2), got {text!r}"
        )
    return value


def _albedo(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected one value or R,G,B in [0, 1], got {text!r}"
        ) from None
    if len(vals) not in (1, 3) or not all(math.isfinite(v) and 0.0 <= v <= 1.0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected one value or R,G,B in [0, 1], got {text!r}")
    return (vals[0], vals[0], vals[0]) if len(vals) == 1 else (vals[0], vals[1], vals[2])


class ListSourcesAction(argparse.Action):
    """`--list-sources`: print the installed lighting sources (`gaffer_envmap.sources`) and exit 0,
    like `--version` (no other argument is needed)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        kwargs.setdefault("help", "list the installed lighting sources (entry points) and exit")
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        from gaffer_envmap.sources import format_source_list

        print(format_source_list())
        parser.exit(0)


def add_source_arguments(
    parser: "argparse.ArgumentParser | argparse._ArgumentGroup", prefix: str = ""
) -> None:
    """`--{prefix}source NAME`, `--{prefix}source-option KEY=VALUE` and `--list-sources`."""
    parser.add_argument(
        f"--{prefix}source",
        metavar="NAME",
        help="a lighting source installed as a plugin (entry-point group gaffer.envmap_sources; "
        "built in: sky), e.g. a text-to-HDR model (--list-sources lists them; "
        "docs/tutorials/skies.md)",
    )
    parser.add_argument(
        f"--{prefix}source-option",
        action="append",
        metavar="KEY=VALUE",
        help="an option of the source, repeatable (e.g. weights=/models/text2light: a local path)",
    )
    parser.add_argument("--list-sources", action=ListSourcesAction)


def add_sky_parser(sub: "argparse._SubParsersAction[argparse.ArgumentParser]") -> None:
    """Add the `sky` subcommand to a `gaffer-envmap` subparsers object."""
    sp = sub.add_parser(
        "sky",
        help="a physical sky (Preetham 1999, CIE overcast) or a studio as an HDR lat-long EXR",
        description=(
            "Write a physical-sky HDR lat-long map in the Blender convention (world z up; azimuth "
            "clockwise from world +y seen from above, as Blender's sun_rotation: 0 = +y = north, "
            "90 = +x = east). Give the sun by angles, by a place and time, or by words."
        ),
    )
    sp.add_argument("--out", required=True, help="output map (.exr, float32; folders are created)")
    sp.add_argument(
        "--width",
        type=_width,
        default=512,
        help=f"columns (even, <= {MAX_WIDTH}); height = width / 2 (default: 512)",
    )
    sp.add_argument(
        "--sun-elevation", type=_number_in(-90, 90), help="degrees above the horizon, [-90, 90]"
    )
    sp.add_argument(
        "--sun-azimuth",
        type=_number_in(-360, 360),
        help="degrees clockwise from world +y (north) seen from above; 90 = +x (east)",
    )
    sp.add_argument(
        "--at",
        metavar="LAT,LON",
        help="a place in decimal degrees, north and east positive (south or west: --at=-33.87,151.21)",
    )
    sp.add_argument(
        "--time",
        metavar="ISO8601",
        help="date and time with a UTC offset, e.g. 2026-06-21T12:00+02:00 (needs --at and the "
        'extra: pip install "gaffer-envmap[sky]")',
    )
    sp.add_argument(
        "--text",
        metavar="PHRASE",
        help='words: "golden hour, hazy, from the left", "overcast noon", "softbox from the left" '
        "(grammar: docs/tutorials/skies.md)",
    )
    sp.add_argument(
        "--strict", action="store_true", help="refuse a --text word the grammar does not know"
    )
    sp.add_argument("--model", choices=SKY_MODELS, help="sky model (default: preetham)")
    lo, hi = TURBIDITY_RANGE
    sp.add_argument(
        "--turbidity",
        type=_number_in(lo, hi),
        help=f"haze, [{lo:g}, {hi:g}]: 2 very clear, 3 clear (default {DEFAULT_TURBIDITY:g}), "
        "6 hazy, 10 thick haze (preetham only)",
    )
    sp.add_argument(
        "--ground-albedo",
        type=_albedo,
        metavar="A|R,G,B",
        help=f"reflectance of the ground below the horizon (default {DEFAULT_GROUND_ALBEDO:g})",
    )
    sp.add_argument(
        "--exposure",
        type=_number_in(-40, 40),
        help=f"scale in stops, 2**EV (default {DEFAULT_EXPOSURE_EV:g}: 1.0 = 8 kcd/m^2, like the "
        "bundled HDRIs; 0: absolute kcd/m^2)",
    )
    sp.add_argument("--no-sun-disc", action="store_true", help="leave the sun's disc out")
    sp.add_argument("--preview", metavar="PNG", help="also write a tone-mapped sRGB preview (.png)")
    add_source_arguments(sp)
    sp.set_defaults(func=cmd_sky)


_SKY_ONLY_FLAGS = (
    ("--sun-elevation", "sun_elevation"),
    ("--sun-azimuth", "sun_azimuth"),
    ("--at", "at"),
    ("--time", "time"),
    ("--model", "model"),
    ("--turbidity", "turbidity"),
    ("--ground-albedo", "ground_albedo"),
    ("--no-sun-disc", "no_sun_disc"),
)


def _check_sources(args: argparse.Namespace) -> None:
    """The sun's sources are complete and do not contradict each other."""
    angles = args.sun_elevation is not None or args.sun_azimuth is not None
    if (args.at is None) != (args.time is None):
        given, missing = ("--at", "--time") if args.time is None else ("--time", "--at")
        raise GafferEnvmapError(
            f"`{given}` needs `{missing}` too: pass --at LAT,LON --time 2026-06-21T12:00+02:00."
        )
    if angles and args.at is not None:
        raise GafferEnvmapError(
            "`--sun-elevation`/`--sun-azimuth` and `--at`/`--time` both give the sun's position; "
            "pass one of them."
        )
    if args.text is None and args.at is None:
        if not angles:
            raise GafferEnvmapError(
                "no sun position: pass --sun-elevation DEG --sun-azimuth DEG, or --at LAT,LON "
                "--time ISO8601, or --text PHRASE."
            )
        if args.sun_elevation is None or args.sun_azimuth is None:
            missing = "--sun-elevation" if args.sun_elevation is None else "--sun-azimuth"
            raise GafferEnvmapError(f"`{missing}` is missing; pass both sun angles (or --text).")


def _resolve_sun(args: argparse.Namespace, reading: object, out: list[str]) -> SunPosition | None:
    """The sun from angles, the ephemeris, or None (the phrase decides)."""
    from gaffer_envmap.phrase import PhraseReading

    phrase = reading if isinstance(reading, PhraseReading) else None
    if args.at is not None:
        from gaffer_envmap.sun_position import (
            parse_place,
            parse_time,
            require_astral,
            sun_position_at,
        )

        lat, lon = parse_place(args.at, "--at")
        when = parse_time(args.time, "--time")
        require_astral()
        sun = sun_position_at(lat, lon, when)
        out.append(
            f"sun at {lat:g},{lon:g} on {when.isoformat()}: elevation {sun.elevation_deg:.2f} deg, "
            f"azimuth {sun.azimuth_deg:.2f} deg (ephemeris: astral)"
        )
        if phrase is not None and (
            phrase.sun_elevation_deg is not None or phrase.sun_azimuth_deg is not None
        ):
            out.append("note: --at/--time replace the phrase's time of day and direction")
        return sun
    if args.sun_elevation is None and args.sun_azimuth is None:
        return None
    el = args.sun_elevation
    az = args.sun_azimuth
    if phrase is not None and (
        (el is not None and phrase.sun_elevation_deg is not None)
        or (az is not None and phrase.sun_azimuth_deg is not None)
    ):
        out.append("note: --sun-elevation/--sun-azimuth replace the phrase's angles")
    if phrase is not None:
        el = phrase.sun_elevation_deg if el is None else el
        az = phrase.sun_azimuth_deg if az is None else az
    from gaffer_envmap.phrase import DEFAULT_SUN

    return SunPosition(
        elevation_deg=DEFAULT_SUN.elevation_deg if el is None else el,
        azimuth_deg=DEFAULT_SUN.azimuth_deg if az is None else az,
    )


@dataclass(frozen=True, kw_only=True)
class _SourcePlan:
    """`--source NAME`: the loaded source and its checked options."""

    source: Any  # gaffer_envmap.sources.EnvmapSource
    options: dict[str, str]

    def describe(self) -> str:
        return f"source {self.source.name}"


def _plan_source(args: argparse.Namespace) -> _SourcePlan:
    """`--source`: the words go to a lighting source; the grammar's own flags do not apply."""
    from gaffer_envmap.sources import load_envmap_source, parse_source_options

    if args.source is None:
        raise GafferEnvmapError(
            "`--source-option` goes with `--source NAME`; pass the source, or drop the option."
        )
    if args.text is None:
        raise GafferEnvmapError(
            f"`--source` {args.source!r} needs `--text PHRASE` (the words it turns into a map)."
        )
    for flag, dest in (*_SKY_ONLY_FLAGS, ("--exposure", "exposure"), ("--strict", "strict")):
        if getattr(args, dest) not in (None, False):
            raise GafferEnvmapError(
                f"`{flag}` applies to the built-in grammar, not to `--source {args.source}`; drop "
                "it (a source takes its own settings as --source-option KEY=VALUE)."
            )
    source = load_envmap_source(args.source)
    if "text" not in source.capabilities:
        raise GafferEnvmapError(
            f"`--source` {args.source!r} estimates light from a photo, not from words; use it "
            f"with gaffer-diffusion insert --light-source {args.source}."
        )
    return _SourcePlan(source=source, options=parse_source_options(args.source_option, source))


def _plan(args: argparse.Namespace, out: list[str]) -> SkyConfig | StudioConfig | _SourcePlan:
    """Every check and the scene to draw, before any pixel is computed."""
    check_output_file("--out", args.out, suffixes=(".exr",))  # before any work
    if args.preview is not None:
        check_output_file("--preview", args.preview, suffixes=(".png",))
    if args.source is not None or args.source_option:
        return _plan_source(args)
    _check_sources(args)
    exposure = DEFAULT_EXPOSURE_EV if args.exposure is None else args.exposure
    reading = None
    if args.text is not None:
        from gaffer_envmap.phrase import read_phrase

        reading = read_phrase(args.text)
        if args.strict and reading.unknown:
            words = ", ".join(repr(w) for w in reading.unknown)
            raise GafferEnvmapError(
                f"`--text` word {words} is not in the grammar (--strict); drop it, use a word "
                "from docs/tutorials/skies.md, or drop --strict to ignore it."
                if len(reading.unknown) == 1
                else f"`--text` words {words} are not in the grammar (--strict); drop them, use "
                "words from docs/tutorials/skies.md, or drop --strict to ignore them."
            )
        out.extend(reading.describe())
        if reading.is_studio:
            for flag, dest in _SKY_ONLY_FLAGS:
                if getattr(args, dest) not in (None, False):
                    raise GafferEnvmapError(
                        f"`{flag}` applies to skies, but --text {args.text!r} describes a studio; "
                        "drop one of them."
                    )
            return reading.scene(exposure_ev=exposure)
    sun = _resolve_sun(args, reading, out)
    if sun is None and reading is not None and reading.sun_elevation_deg is None:
        from gaffer_envmap.phrase import DEFAULT_SUN

        out.append(
            f"note: no time of day in --text: the sun at elevation {DEFAULT_SUN.elevation_deg:g} "
            f"deg (add a time of day or --sun-elevation)"
        )
    base = reading.scene(exposure_ev=exposure, sun=sun) if reading is not None else None
    if isinstance(base, SkyConfig):
        model, turbidity, tint, sun = base.model, base.turbidity, base.tint_rgb, base.sun
    else:
        model, turbidity, tint = "preetham", DEFAULT_TURBIDITY, (1.0, 1.0, 1.0)
    if sun is None:  # _check_sources makes this unreachable
        raise ParameterError("no sun position: pass --sun-elevation and --sun-azimuth.")
    return SkyConfig(
        sun=sun,
        model=args.model or model,
        turbidity=turbidity if args.turbidity is None else args.turbidity,
        ground_albedo=args.ground_albedo
        or (DEFAULT_GROUND_ALBEDO, DEFAULT_GROUND_ALBEDO, DEFAULT_GROUND_ALBEDO),
        exposure_ev=exposure,
        tint_rgb=tint,
        sun_disc=not args.no_sun_disc,
    )


def cmd_sky(args: argparse.Namespace) -> int:
    """Run `gaffer-envmap sky` (arguments from `add_sky_parser`)."""
    lines: list[str] = []
    scene = _plan(args, lines)
    from gaffer_envmap.io import write_png
    from gaffer_envmap.io_exr import write_exr
    from gaffer_envmap.studio import studio_envmap

    if isinstance(scene, _SourcePlan):
        from gaffer_envmap.sources import envmap_from_text

        env = envmap_from_text(scene.source, args.text, width=args.width, options=scene.options)
        note = env.metadata.get("gaffer:source_note")
        if note:
            lines.append(f"note: the map of source {scene.source.name!r}: {note}")
    elif isinstance(scene, StudioConfig):
        env = studio_envmap(scene, args.width)
    else:
        from gaffer_envmap.sky import sky_envmap

        if scene.model != "preetham" and args.turbidity is not None:
            lines.append(f"note: --turbidity is not used by the {scene.model} model")
        env = sky_envmap(scene, args.width)
    for line in lines:
        print(line)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    # what made the map travels in its header (string attributes; `gaffer-envmap info` reads it back)
    header = {"gaffer:convention": env.convention, "gaffer:alignment": env.alignment}
    write_exr(out, env.radiance_linear, attributes={**header, **env.metadata})
    wrote = f"wrote {out} ({env.width}x{env.height}, Blender convention; {scene.describe()})"
    if args.preview is not None:
        from gaffer_envmap.preview import tonemap_preview

        preview = Path(args.preview)
        preview.parent.mkdir(parents=True, exist_ok=True)
        write_png(preview, tonemap_preview(env.radiance_linear))
        wrote += f" and {preview}"
    print(wrote)
    return 0
