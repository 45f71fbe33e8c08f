"""Read and write environment maps and images; the format is chosen from the file suffix.

| suffix | read | write | notes |
|---|---|---|---|
| `.exr` | yes | yes | OpenEXR (`io_exr`): validated before decoding; float32 (default) or half |
| `.hdr` | yes | yes | Radiance RGBE via OpenImageIO (`pip install "gaffer-envmap[hdr]"`) |
| `.png`, `.jpg`, `.jpeg` | yes | `write_png` | 8-bit; decoded to linear with an explicit `encoding` |

`read_envmap` returns an `EnvironmentMap` (2:1, RGB, sanitized); `read_image_array` returns whatever
the file holds as float32 `[H, W, C]` with no shape check and no sanitizing.
"""

import logging
import os
from pathlib import Path

import numpy as np

from gaffer_envmap.environment_map import EnvironmentMap, PixelAlignment
from gaffer_envmap.errors import (
    EnvmapReadError,
    EnvmapWriteError,
    MissingDependencyError,
    ShapeError,
)
from gaffer_envmap.io_exr import (
    ExrCompression,
    ExrDtype,
    HalfOverflowPolicy,
    read_exr,
    write_exr,
)
from gaffer_envmap.io_hdr import read_hdr, require_openimageio, write_hdr
from gaffer_envmap.io_ldr import LdrEncoding, decode_to_linear, read_ldr
from gaffer_envmap.sanitize import SanitizePolicy
from gaffer_envmap.sanitize import sanitize as _sanitize
from gaffer_envmap.writers import write_png as _write_png

__all__ = [
    "READ_SUFFIXES",
    "WRITE_SUFFIXES",
    "check_write_suffix",
    "read_envmap",
    "read_image_array",
    "write_envmap",
    "write_png",
]

logger = logging.getLogger(__name__)

READ_SUFFIXES = (".exr", ".hdr", ".png", ".jpg", ".jpeg")
WRITE_SUFFIXES = (".exr", ".hdr")
_LDR_SUFFIXES = (".png", ".jpg", ".jpeg")


def _read_suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix not in READ_SUFFIXES:
        raise EnvmapReadError(
            f"`path` {str(path)!r} has suffix {path.suffix!r}; supported: "
            f"{', '.join(READ_SUFFIXES)}. Rename the file or convert it."
        )
    if not path.exists():
        raise EnvmapReadError(f"`path` {str(path)!r} does not exist.")
    if not path.is_file():
        raise EnvmapReadError(f"`path` {str(path)!r} is not a regular file.")
    return suffix


def _read_pixels(path: Path) -> tuple[np.ndarray, dict[str, str]]:
    suffix = _read_suffix(path)
    if suffix == ".exr":
        return read_exr(path)
    meta = {"source_path": str(path), "format": suffix.lstrip(".").replace("jpeg", "jpg")}
    if suffix == ".hdr":
        return read_hdr(path), meta
    return read_ldr(path), meta


def read_image_array(path: str | os.PathLike[str]) -> np.ndarray:
    """Read any supported image as float32 `[H, W, C]`, without shape check or sanitizing.

    Args:
        path: `.exr`, `.hdr`, `.png`, `.jpg` or `.jpeg` file.

    Returns:
        EXR: `[H, W, 3]` or `[H, W, 4]` as stored (Y becomes grey RGB; NaN/Inf kept).
        HDR: `[H, W, 3]` linear. PNG/JPEG: `[H, W, C]` (C = 1..4) *encoded* values in [0, 1].

    Raises:
        EnvmapReadError: missing file, unsupported suffix, damaged or unsupported content.
        MissingDependencyError: `.hdr` without OpenImageIO.

    Example:
        >>> import tempfile
        >>> p = tempfile.mkdtemp() + "/cube.exr"
        >>> write_exr(p, np.zeros((12, 2, 3), np.float32))
        >>> read_image_array(p).shape
        (12, 2, 3)
    """
    return _read_pixels(Path(path))[0]


def _to_rgb(pixels: np.ndarray, path: Path) -> np.ndarray:
    channels = pixels.shape[2]
    if channels == 3:
        return pixels
    if channels == 4:
        return pixels[..., :3]  # alpha carries no light
    if channels in (1, 2):
        return np.repeat(pixels[..., :1], 3, axis=2)  # grey (+ alpha)
    raise EnvmapReadError(
        f"`path` {str(path)!r} has {channels} channels; an environment map needs 1 (grey), "
        "3 (RGB) or 4 (RGBA)."
    )


def _check_latlong(rgb: np.ndarray, path: Path, meta: dict[str, str]) -> None:
    height, width = rgb.shape[:2]
    if width == 2 * height:
        return
    if meta.get("envmap") == "cube":
        fix = (
            "It is an OpenEXR cube map (6 faces stacked vertically): convert it with "
            "`gaffer_envmap.cube.cube_to_latlong(read_image_array(path), out_height)`."
        )
    else:
        fix = (
            "A lat-long map is twice as wide as it is high. Use `read_image_array(path)` to load "
            "other images, and crop or resample to 2:1."
        )
    raise ShapeError(f"image in {str(path)!r}", (height, width, 3), "[He, 2*He, 3]", fix)


def read_envmap(
    path: str | os.PathLike[str],
    *,
    sanitize: SanitizePolicy = "raise",
    convention: str = "blender",
    alignment: PixelAlignment = "center",
    encoding: LdrEncoding = "srgb",
) -> EnvironmentMap:
    """Read an equirectangular environment map.

    Args:
        path: `.exr`, `.hdr`, `.png`, `.jpg` or `.jpeg` file, 2:1 lat-long.
        sanitize: what to do with NaN, ±Inf and negative values: "raise" (default: tiny negatives
            from lossy compression become 0 with an INFO line, anything else raises), "strict"
            (raise on any), "zero" or "clamp" (see `gaffer_envmap.sanitize.SanitizePolicy`).
        convention: the lat-long convention the file uses (`gaffer_envmap.conventions`); files do
            not record it. Maps carrying OpenEXR's `envmap=latlong` attribute are in "openexr",
            corner-aligned (pass `convention="openexr", alignment="corner"`).
        alignment: "center" (default) or "corner" pixel alignment of the file.
        encoding: for PNG/JPEG only, how 8-bit values encode linear light ("srgb" default,
            "gamma2.2", "linear"); ignored for HDR formats.

    Returns:
        An `EnvironmentMap` with `[He, 2*He, 3]` float32 linear radiance (alpha dropped, grey
        expanded to RGB); `metadata` holds the source path, format, EXR attributes (`envmap`,
        compression, windows, string attributes) and, when sanitizing changed values, `sanitize`.

    Raises:
        EnvmapReadError: missing file, unsupported suffix, damaged/unsupported file, or no
            usable colour channels.
        ShapeError: the image is not 2:1 (the message says what to do, e.g. for cube maps).
        NonFiniteError: NaN/Inf or substantial negative values with `sanitize="raise"`, any of
            them with "strict".
        ConventionError: unknown `convention`.
        MissingDependencyError: `.hdr` without OpenImageIO.

    Example:
        >>> import tempfile
        >>> p = tempfile.mkdtemp() + "/env.exr"
        >>> write_envmap(p, np.ones((4, 8, 3), np.float32))
        >>> env = read_envmap(p)
        >>> env.height, env.width, env.convention
        (4, 8, 'blender')
    """
    path = Path(path)
    pixels, meta = _read_pixels(path)
    rgb = _to_rgb(pixels, path)
    if path.suffix.lower() in _LDR_SUFFIXES:
        rgb = decode_to_linear(rgb, encoding)
        meta["encoding"] = encoding
    _check_latlong(rgb, path, meta)
    rgb, report = _sanitize(rgb, sanitize, name=str(path))
    if report.tiny_negatives_clamped:
        meta["sanitize"] = f"tiny negatives set to 0: {report.describe()}"
    elif not report.clean:
        meta["sanitize"] = f"{report.policy}: {report.describe()}"
    if meta.get("envmap") == "latlong" and convention != "openexr":
        logger.info(
            "%s carries envmap=latlong (OpenEXR convention, corner-aligned) but is read as %r",
            path,
            convention,
        )
    return EnvironmentMap(
        radiance_linear=rgb, convention=convention, alignment=alignment, metadata=meta
    )


def _envmap_array(env_or_array: EnvironmentMap | np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
    if isinstance(env_or_array, EnvironmentMap):
        attrs = {
            "gaffer:convention": env_or_array.convention,
            "gaffer:alignment": env_or_array.alignment,
        }
        return env_or_array.radiance_linear, attrs
    arr = np.asarray(env_or_array)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[1] != 2 * arr.shape[0] or arr.shape[0] < 1:
        raise ShapeError(
            "env_or_array",
            arr.shape,
            "[He, 2*He, 3]",
            "Pass a 2:1 RGB lat-long map (drop alpha with `arr[..., :3]`); write other images "
            "with `gaffer_envmap.io_exr.write_exr`.",
        )
    return arr, {}


def write_envmap(
    path: str | os.PathLike[str],
    env_or_array: EnvironmentMap | np.ndarray,
    *,
    dtype: ExrDtype = "float32",
    overflow: HalfOverflowPolicy = "raise",
    compression: ExrCompression = "zip",
) -> None:
    """Write an environment map, atomically; the format comes from the suffix (`.exr`, `.hdr`).

    Args:
        path: destination ending in `.exr` or `.hdr`.
        env_or_array: an `EnvironmentMap` (its convention and alignment are stored as EXR string
            attributes `gaffer:convention` / `gaffer:alignment`) or a `[He, 2*He, 3]` array of
            linear radiance.
        dtype: EXR only: "float32" (default) or "half".
        overflow: EXR half only: "raise" (default) or "clamp" values beyond ±65504.
        compression: EXR only, default "zip" (lossless).

    Raises:
        ShapeError: the array is not `[He, 2*He, 3]`.
        HalfOverflowError: half output with a finite |value| > 65504 and `overflow="raise"`.
        NonFiniteError: `.hdr` output with NaN/Inf values.
        ValueError: `dtype="half"` for a `.hdr` file, or an unknown option value.
        EnvmapWriteError: unsupported suffix, or the write failed (an existing file is left
            untouched).
        MissingDependencyError: `.hdr` without OpenImageIO.
    """
    arr, attrs = _envmap_array(env_or_array)
    target = Path(path)
    suffix = check_write_suffix(target)
    if suffix == ".exr":
        write_exr(
            target, arr, dtype=dtype, overflow=overflow, compression=compression, attributes=attrs
        )
    elif suffix == ".hdr":
        if dtype != "float32":
            raise ValueError(f"`dtype` {dtype!r} applies to .exr only; RGBE has one format.")
        write_hdr(target, arr)


def check_write_suffix(path: str | os.PathLike[str], argument: str = "path") -> str:
    """The lower-case suffix of an environment-map destination, once its writer is known to be
    installed: `write_envmap` calls it first, a command line before any work.

    Args:
        path: the destination.
        argument: the name the message gives the path (a CLI passes its own, e.g. `dst`).

    Returns:
        ".exr" or ".hdr".

    Raises:
        EnvmapWriteError: a suffix other than `WRITE_SUFFIXES` (8-bit images named as such).
        MissingDependencyError: `.hdr` without OpenImageIO (`pip install "gaffer-envmap[hdr]"`).
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix in _LDR_SUFFIXES:
        raise EnvmapWriteError(
            f"`{argument}` {str(target)!r}: an 8-bit image cannot hold HDR radiance. Tone-map / "
            "encode it (e.g. `gaffer_envmap.encode`) and write it with `write_png`, or pass a .exr "
            "or .hdr file."
        )
    if suffix not in WRITE_SUFFIXES:
        raise EnvmapWriteError(
            f"`{argument}` {str(target)!r} has suffix {target.suffix or '(none)'!r}; supported: "
            f"{', '.join(WRITE_SUFFIXES)}."
        )
    if suffix == ".hdr":
        try:
            require_openimageio()
        except MissingDependencyError as exc:
            raise MissingDependencyError(
                f"`{argument}` {str(target)!r}: {exc}; or write a .exr file."
            ) from exc
    return suffix


def write_png(path: str | os.PathLike[str], rgb01_or_uint8: np.ndarray) -> None:
    """Write an 8-bit PNG (16-bit for uint16 input), atomically (`gaffer_envmap.writers.write_png`).

    Args:
        path: destination `.png`.
        rgb01_or_uint8: `[H, W]` or `[H, W, 1|2|3|4]`; uint8 (or uint16) written as is, floats in
            [0, 1] clipped and quantised (`gaffer_envmap.writers.quantize`: nearest, ties to even).

    Raises:
        ShapeError: wrong shape or dtype.
        NonFiniteError: NaN/Inf in float input.
        EnvmapWriteError: suffix is not `.png`, or the write failed.
    """
    if Path(path).suffix.lower() != ".png":
        raise EnvmapWriteError(f"`path` {str(path)!r} must end in '.png'.")
    _write_png(path, rgb01_or_uint8)
