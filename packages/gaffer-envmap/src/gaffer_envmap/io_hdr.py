"""Radiance RGBE (`.hdr`) read/write through OpenImageIO (the optional extra `gaffer-envmap[hdr]`).

RGBE stores a shared 8-bit exponent per pixel, so each channel is exact to about 1/256 of the
pixel's largest channel (smaller channels lose relative precision), and it cannot hold NaN, Inf or
negative values. Files with any of the 8 scan orientations ("-Y h +X w" is the standard one) are
returned upright (OpenImageIO's `reorient`).
"""

import logging
import os
from pathlib import Path
from types import ModuleType

import numpy as np

from gaffer_envmap._exr_header import MAX_PIXELS, MAX_SIDE
from gaffer_envmap.atomic import atomic_write
from gaffer_envmap.errors import (
    EnvmapReadError,
    EnvmapWriteError,
    MissingDependencyError,
    NonFiniteError,
    ShapeError,
)

__all__ = ["read_hdr", "require_openimageio", "write_hdr"]

logger = logging.getLogger(__name__)

_INSTALL_HINT = 'pip install "gaffer-envmap[hdr]"'


def require_openimageio() -> None:
    """Refuse early when OpenImageIO (the `.hdr` reader and writer) is not installed.

    Raises:
        MissingDependencyError: with the exact pip command.
    """
    _oiio()


def _oiio() -> ModuleType:
    try:
        import OpenImageIO
    except ImportError as exc:
        raise MissingDependencyError(
            f"Radiance .hdr files need OpenImageIO, which is not installed. Run: {_INSTALL_HINT}"
        ) from exc
    return OpenImageIO


def _header(oiio: ModuleType, path: Path) -> tuple[int, int, int, int]:
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise EnvmapReadError(
            f"`path` {str(path)!r} could not be opened as an image ({oiio.geterror()})."
        )
    try:
        spec, fmt = inp.spec(), inp.format_name()
    finally:
        inp.close()
    if fmt != "hdr":
        raise EnvmapReadError(
            f"`path` {str(path)!r} holds a {fmt!r} image, not Radiance RGBE; rename it to the "
            "right suffix."
        )
    w, h, c = spec.width, spec.height, spec.nchannels
    if not (0 < w <= MAX_SIDE and 0 < h <= MAX_SIDE and w * h <= MAX_PIXELS):
        raise EnvmapReadError(
            f"`path` {str(path)!r} declares a {w} x {h} image, outside the supported range "
            f"(1..{MAX_SIDE} a side, at most {MAX_PIXELS} pixels); the file is probably corrupt."
        )
    return w, h, c, spec.get_int_attribute("Orientation", 1)


def read_hdr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a Radiance `.hdr` file.

    Args:
        path: the file.

    Returns:
        `[H, W, 3]` float32 linear RGB, row 0 at the top.

    Raises:
        EnvmapReadError: missing, corrupt, truncated or not RGBE.
        MissingDependencyError: OpenImageIO is not installed (`pip install "gaffer-envmap[hdr]"`).
    """
    path = Path(path)
    if not path.is_file():
        raise EnvmapReadError(f"`path` {str(path)!r} does not exist (or is not a file).")
    oiio = _oiio()
    w, h, c, orientation = _header(oiio, path)
    buf = oiio.ImageBuf(str(path))
    if orientation != 1:
        buf = oiio.ImageBufAlgo.reorient(buf)
    pixels = buf.get_pixels(oiio.FLOAT)
    if buf.has_error or pixels is None:
        raise EnvmapReadError(
            f"`path` {str(path)!r} could not be decoded ({buf.geterror() or 'no pixels'}); "
            "the file is probably truncated or corrupt."
        )
    pixels = np.asarray(pixels, dtype=np.float32)
    expected = (h, w, c) if orientation <= 4 else (w, h, c)  # 5..8 transpose the image
    if pixels.shape != expected or c != 3:
        raise EnvmapReadError(
            f"`path` {str(path)!r} decoded to shape {pixels.shape}, expected {expected} with 3 "
            "channels (RGB)."
        )
    return np.ascontiguousarray(pixels)


def write_hdr(path: str | os.PathLike[str], rgb: np.ndarray) -> None:
    """Write `[H, W, 3]` linear RGB as a Radiance `.hdr` file, atomically.

    Negative values cannot be stored in RGBE and are written as 0 (a warning is logged with the
    count).

    Args:
        path: destination; must end in `.hdr` (OpenImageIO picks the format from the suffix).
        rgb: `[H, W, 3]` real array.

    Raises:
        ShapeError: `rgb` is not `[H, W, 3]`.
        NonFiniteError: `rgb` holds NaN or Inf (sanitize it first, `gaffer_envmap.sanitize`).
        EnvmapWriteError: the write failed; an existing file at `path` is left untouched.
        MissingDependencyError: OpenImageIO is not installed.
    """
    if Path(path).suffix.lower() != ".hdr":
        raise EnvmapWriteError(
            f"`path` {str(path)!r} must end in '.hdr' (OpenImageIO picks the format from the suffix)."
        )
    arr = np.asarray(rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or 0 in arr.shape:
        raise ShapeError("rgb", arr.shape, "[H, W, 3]", "Drop alpha with `rgb[..., :3]`.")
    arr = np.ascontiguousarray(arr, dtype=np.float32)
    if not np.isfinite(arr).all():
        raise NonFiniteError(
            f"`rgb` holds {int((~np.isfinite(arr)).sum())} NaN/Inf value(s), which RGBE cannot "
            'store. Clean it with `gaffer_envmap.sanitize.sanitize(rgb, "clamp")` first.'
        )
    negative = int((arr < 0).sum())
    if negative:
        logger.warning("writing %d negative value(s) as 0 (RGBE cannot store them)", negative)
        arr = np.maximum(arr, 0.0)
    oiio = _oiio()
    height, width = arr.shape[:2]

    def _write(tmp: Path) -> None:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise EnvmapWriteError(
                f"OpenImageIO has no writer for {tmp.suffix!r} ({oiio.geterror()})."
            )
        try:
            if not out.open(str(tmp), oiio.ImageSpec(width, height, 3, "float")):
                raise EnvmapWriteError(out.geterror())
            if not out.write_image(arr):
                raise EnvmapWriteError(out.geterror())
        finally:
            out.close()

    atomic_write(path, _write)
