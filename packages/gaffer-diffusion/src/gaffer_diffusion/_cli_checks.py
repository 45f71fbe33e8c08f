"""Cheap checks of command-line arguments, run before torch is imported or a model is loaded.

Each check raises `ConfigError` (a value or a combination of flags is wrong) or `InputValueError` (a
file is missing, empty or not what it should be) with one line that names the flag, the value and
the fix. Nothing here imports torch, diffusers or numpy: a refusal takes a fraction of a second.
"""

import math
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from gaffer_diffusion.errors import ConfigError, InputValueError
from gaffer_envmap.cli_support import check_not_an_input, check_output_dir, check_output_file
from gaffer_envmap.errors import OutputPathError

MAX_STEPS = 1000
"""The noise schedule has 1000 training timesteps; more sampling steps than that do not exist."""

MAX_FRAMES = 3600
"""Most turntable frames (one every 0.1 degree); the memory check below usually binds first."""

MAX_FPS = 100.0
"""GIF frame delays are counted in 10 ms units: 100 fps is the fastest a GIF can say."""

MAX_BATCH = 1024
MAX_AVERAGE_SAMPLES = 256
MAX_SIDE = 8192
"""Largest `prepare --size` (an 8192 px float32 RGBA square is about 1 GiB)."""

MAX_SEED = 2**63 - 1


def need_path(flag: str, path: Path, what: str) -> None:
    """`path` exists (file or folder)."""
    if not path.exists():
        raise InputValueError(f"`{flag}` {path} does not exist; pass {what}.")


def need_file(flag: str, path: Path, what: str) -> None:
    """`path` is a non-empty, readable file."""
    need_path(flag, path, what)
    if path.is_dir():
        raise InputValueError(f"`{flag}` {path} is a folder, not a file; pass {what}.")
    if not os.access(path, os.R_OK):
        raise InputValueError(f"`{flag}` {path} is not readable (permissions); pass {what}.")
    if path.stat().st_size == 0:
        raise InputValueError(f"`{flag}` {path} is empty (0 bytes); pass {what}.")


def need_dir(flag: str, path: Path, what: str) -> None:
    """`path` is an existing folder."""
    need_path(flag, path, what)
    if not path.is_dir():
        raise InputValueError(f"`{flag}` {path} is a file, not a folder; pass {what}.")


def image_size(flag: str, path: Path) -> tuple[int, int]:
    """(width, height) of an image file, read from its header only; refuses non-images and 1x1."""
    need_file(flag, path, "a PNG, JPEG or WebP image")
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            w, h = im.size
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise InputValueError(
            f"`{flag}` {path} is not a readable image ({exc}); pass a PNG, JPEG or WebP image."
        ) from exc
    if min(w, h) < 8:
        raise InputValueError(
            f"`{flag}` {path} is {w}x{h} px; pass an image of at least 8x8 px showing the object."
        )
    return w, h


_MAGIC = {".exr": (b"\x76\x2f\x31\x01",), ".hdr": (b"#?",)}
"""First bytes of an OpenEXR file and of a Radiance RGBE file (`#?RADIANCE` / `#?RGBE`)."""


def envmap_file(flag: str, path: Path) -> None:
    """A non-empty .exr / .hdr file whose first bytes are that format's (no pixels decoded)."""
    need_file(flag, path, "an equirectangular .exr or .hdr map")
    magic = _MAGIC.get(path.suffix.lower())
    if magic is None:
        raise InputValueError(
            f"`{flag}` {path} is not an .exr or .hdr file; pass an equirectangular HDR map."
        )
    with open(path, "rb") as f:
        head = f.read(4)
    if not head.startswith(magic):
        raise InputValueError(
            f"`{flag}` {path} is not a valid {path.suffix.lower()} file (wrong first bytes); "
            "re-export or re-download it."
        )


def _own_error(check: Callable[[], None]) -> None:
    """Run a shared output-path check (`gaffer_envmap.cli_support`, one definition for the four CLIs)
    and raise its refusal as this package's `ConfigError`."""
    try:
        check()
    except OutputPathError as exc:
        raise ConfigError(str(exc)) from exc


def writable_file(
    flag: str,
    path: Path,
    *,
    siblings: Iterable[Path] = (),
    suffixes: Iterable[str] | None = None,
) -> None:
    """`path` can be written as a file: not a folder, and its folder exists or can be made, writable;
    none of `siblings` (files written beside it, e.g. `OUT.mask.png`) is a folder; its suffix is one
    of `suffixes` (the formats the command writes) when given."""
    _own_error(lambda: check_output_file(flag, path, siblings=siblings, suffixes=suffixes))


def writable_dir(
    flag: str, path: Path, *, files: Iterable[str] = (), folders: Iterable[str] = ()
) -> None:
    """`path` can be written as a folder (it exists as one, writable, or can be created); the files
    and sub-folders the command writes in it are not of the other kind (`check_output_dir`)."""
    if str(path) in ("", "."):
        raise ConfigError(f"`{flag}` is empty or the current folder; pass a new output folder.")
    _own_error(lambda: check_output_dir(flag, path, files=files, folders=folders))


def not_an_input(flag: str, path: Path, inputs: Iterable[tuple[str, object]]) -> None:
    """`path` is none of the command's input files (writing it would replace the input); entries
    that are not paths (None, 'auto') are skipped."""
    paths = [(name, p) for name, p in inputs if isinstance(p, Path)]
    _own_error(lambda: check_not_an_input(flag, path, paths))


def replaceable_dir(flag: str, path: Path) -> None:
    """`path` can be built beside itself and renamed into place (`atomic_dir`): its parent is
    writable, and an existing `path` is a folder."""
    writable_dir(flag, path)
    parent = path.absolute().parent
    if parent.is_dir():
        try:  # the output is built in a sibling: the parent must take a new entry
            check_output_dir(flag, parent)
        except OutputPathError as exc:
            raise ConfigError(
                f"`{flag}` {path}: its folder {parent} is not writable, and the output is built "
                "beside it and renamed into place; pass a folder in a writable place."
            ) from exc


def int_range(flag: str, value: int | None, lo: int, hi: int, fix: str = "") -> None:
    """`lo <= value <= hi` (None passes: the default applies)."""
    if value is not None and not lo <= value <= hi:
        tail = f" ({fix})" if fix else ""
        raise ConfigError(f"`{flag}` is {value}; expected an integer in [{lo}, {hi}]{tail}.")


def channel_widths(
    flag: str, text: str | None, levels: tuple[int, int] = (2, 6)
) -> tuple[int, ...] | None:
    """Comma-separated positive channel counts, `levels[0]` to `levels[1]` of them, each a multiple
    of 8 (the group norms' groups); None passes (the default applies)."""
    if text is None:
        return None
    parts = text.split(",")
    widths = tuple(int(v) for v in parts if v.strip().isdigit())
    if (
        len(widths) != len(parts)
        or not levels[0] <= len(widths) <= levels[1]
        or any(w <= 0 or w % 8 for w in widths)
    ):
        raise ConfigError(
            f"`{flag}` is {text!r}; pass {levels[0]} to {levels[1]} comma-separated multiples of 8, "
            "e.g. 16,32,64,96."
        )
    return widths


def finite(
    flag: str,
    value: float | None,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
) -> None:
    """`value` is finite and in [lo, hi] (or (lo, hi] with `lo_open`); None passes."""
    if value is None:
        return
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        left = "(" if lo_open else "["
        raise ConfigError(
            f"`{flag}` is {value}; expected a finite number in {left}{lo:g}, {hi:g}]."
        )


def available_memory() -> int | None:
    """Bytes of memory available now (Linux `MemAvailable`), or None when unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def fits_in_memory(flag: str, need: int, what: str) -> None:
    """Refuse a value whose outputs would need more than the memory available, saying how much."""
    have = available_memory()
    if have is not None and need > have:
        raise ConfigError(
            f"`{flag}` would need about {need / 2**30:.1f} GiB for {what}, but {have / 2**30:.1f} GiB "
            "is available; pass a smaller value."
        )
