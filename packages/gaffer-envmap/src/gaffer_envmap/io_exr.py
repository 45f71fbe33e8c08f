"""OpenEXR read/write through the `OpenEXR` Python bindings (`OpenEXR.File`, openexr >= 3.3).

Reading is defensive: every file is first checked by a pure-Python structural validator
(`gaffer_envmap._exr_header`: header attributes, windows, chunk table, chunk headers) so that a
damaged file is refused with `EnvmapReadError` before native code can crash, hang or allocate
gigabytes on it. All 185 fuzzer-made files of the OpenEXR project's `Damaged/` collection are
refused this way.

What is read:

- single- and multi-part files; the first part with R, G, B channels (else the first with Y);
- scan-line and tiled files; for mip/rip-mapped files, the full-resolution level only;
- half, float and uint channels, all returned as float32;
- RGB -> `[H, W, 3]`, RGBA -> `[H, W, 4]`, Y -> grey `[H, W, 3]`, YA -> `[H, W, 4]`;
- the data window (not the display window); both are recorded in the metadata, as are the `envmap`
  attribute ("latlong" / "cube"), the compression, the part name and every string attribute.

What is refused (`EnvmapReadError`, message says why): damaged files, deep data, subsampled
(luminance/chroma) channels, ZSTD/LJ2K compression, images above 65536 px a side or 2^28 pixels,
parts without RGB or Y channels (e.g. `WideFloatRange.exr`, which has only G).

Non-finite values are returned as they are; `gaffer_envmap.io.read_envmap` applies the sanitize
policy. A non-2:1 image (a cube map, `BrightRings.exr`) reads fine here; `read_envmap` refuses it.
"""

import logging
import os
from pathlib import Path
from types import ModuleType
from typing import Any, Literal, assert_never, get_args

import numpy as np

from gaffer_envmap._exr_header import (
    COMPRESSION_NAMES,
    PIXEL_TYPE_NAMES,
    ExrCorruptError,
    ExrFileInfo,
    ExrPartInfo,
    validate_exr,
)
from gaffer_envmap.atomic import atomic_write
from gaffer_envmap.errors import EnvmapReadError, HalfOverflowError, ShapeError

__all__ = [
    "HALF_MAX",
    "ExrCompression",
    "ExrDtype",
    "HalfOverflowPolicy",
    "read_exr",
    "read_exr_array",
    "write_exr",
]

logger = logging.getLogger(__name__)

HALF_MAX = 65504.0
"""Largest finite half-float value."""

ExrDtype = Literal["float32", "half"]
HalfOverflowPolicy = Literal["raise", "clamp"]
ExrCompression = Literal[
    "none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab"
]
_ENVMAP_NAMES = {0: "latlong", 1: "cube"}


def _openexr() -> ModuleType:
    import OpenEXR  # a hard dependency, imported late so `import gaffer_envmap` stays light

    return OpenEXR


# ----------------------------------------------------------------------------------------------
# reading


def _validate(path: Path) -> ExrFileInfo:
    try:
        return validate_exr(path)
    except FileNotFoundError as exc:
        raise EnvmapReadError(f"`path` {str(path)!r} does not exist.") from exc
    except IsADirectoryError as exc:
        raise EnvmapReadError(f"`path` {str(path)!r} is a directory, not an EXR file.") from exc
    except ExrCorruptError as exc:
        if exc.unsupported:
            raise EnvmapReadError(
                f"`path` {str(path)!r} uses an unsupported OpenEXR feature: {exc.reason}. "
                "Convert it to a plain scan-line RGB(A) EXR (e.g. `oiiotool in.exr -o out.exr`)."
            ) from exc
        raise EnvmapReadError(
            f"`path` {str(path)!r} is not a valid OpenEXR file ({exc.reason}); it was refused "
            "before decoding. Re-export or re-download it."
        ) from exc
    except OSError as exc:
        raise EnvmapReadError(f"`path` {str(path)!r} could not be read: {exc}") from exc


def _pick_part(info: ExrFileInfo, path: Path) -> tuple[ExrPartInfo, tuple[str, ...]]:
    for wanted in (("R", "G", "B"), ("Y",)):
        for part in info.parts:
            names = {c.name for c in part.channels}
            if set(wanted) <= names:
                return part, (*wanted, "A") if "A" in names else wanted
    found = [sorted(c.name for c in p.channels) for p in info.parts]
    raise EnvmapReadError(
        f"`path` {str(path)!r} has no part with R, G, B (or Y) channels; its parts hold "
        f"channels {found}. Rename the channels to R, G, B when exporting."
    )


def _decode(path: Path, info: ExrFileInfo) -> Any:  # an OpenEXR.File
    exr = _openexr()
    try:
        decoded = exr.File(str(path), separate_channels=True)
        parts = decoded.parts
    except Exception as exc:  # the bindings raise RuntimeError, UnicodeDecodeError, ...
        raise EnvmapReadError(
            f"`path` {str(path)!r}: OpenEXR could not decode it ({type(exc).__name__}: {exc}). "
            "The file is probably corrupt; re-export it."
        ) from exc
    # The bindings drop a part whose pixels fail to decode (and print a warning) instead of raising.
    if len(parts) != len(info.parts):
        raise EnvmapReadError(
            f"`path` {str(path)!r}: OpenEXR decoded {len(parts)} of its {len(info.parts)} "
            "part(s); the pixel data is corrupt. Re-export the file."
        )
    return decoded


def _channel_array(path: Path, part: Any, name: str, shape: tuple[int, int]) -> np.ndarray:
    channel = part.channels.get(name)
    pixels = None if channel is None else np.asarray(channel.pixels)
    if pixels is None or pixels.shape != shape:
        got = None if pixels is None else pixels.shape
        raise EnvmapReadError(
            f"`path` {str(path)!r}: channel {name!r} decoded to shape {got}, expected {shape}; "
            "the file is corrupt."
        )
    return pixels.astype(np.float32)


def _metadata(
    path: Path, part_info: ExrPartInfo, part: Any, channels: tuple[str, ...]
) -> dict[str, str]:
    meta = {
        "source_path": str(path),
        "format": "exr",
        "exr_part": str(part_info.index if part_info.name is None else part_info.name),
        "exr_channels": ",".join(channels),
        "exr_pixel_type": ",".join(
            PIXEL_TYPE_NAMES[c.pixel_type] for c in part_info.channels if c.name in channels
        ),
        "exr_compression": COMPRESSION_NAMES[part_info.compression],
        "exr_storage": part_info.storage,
        "data_window": ",".join(map(str, part_info.data_window)),
        "display_window": ",".join(map(str, part_info.display_window)),
    }
    if part_info.envmap is not None:
        meta["envmap"] = _ENVMAP_NAMES.get(part_info.envmap, str(part_info.envmap))
    for key, value in part.header.items():
        if isinstance(value, str) and key not in ("name", "type"):
            meta[key] = value
    return meta


def read_exr(path: str | os.PathLike[str]) -> tuple[np.ndarray, dict[str, str]]:
    """Read an OpenEXR image as float32 pixels plus metadata (see the module docstring).

    Args:
        path: an `.exr` file.

    Returns:
        `(pixels, metadata)`: `pixels` is `[H, W, 3]` (RGB, or grey from Y) or `[H, W, 4]` (with
        alpha) float32, row 0 = top of the data window, values as stored (NaN/Inf kept).
        `metadata` maps strings to strings (`envmap`, `exr_compression`, `data_window`, ...).

    Raises:
        EnvmapReadError: missing, damaged or unsupported file, or no RGB/Y channels.

    Example:
        >>> import tempfile, numpy as np
        >>> p = tempfile.mkdtemp() + "/a.exr"
        >>> write_exr(p, np.ones((2, 4, 3), np.float32), envmap="latlong")
        >>> px, meta = read_exr(p)
        >>> px.shape, meta["envmap"]
        ((2, 4, 3), 'latlong')
    """
    path = Path(path)
    info = _validate(path)
    part_info, channels = _pick_part(info, path)
    decoded = _decode(path, info)
    part = decoded.parts[part_info.index]
    shape = (part_info.height, part_info.width)
    planes = [_channel_array(path, part, name, shape) for name in channels]
    if channels[0] == "Y":
        planes = [planes[0]] * 3 + planes[1:]
    pixels = np.stack(planes, axis=-1)
    return pixels, _metadata(path, part_info, part, channels)


def read_exr_array(path: str | os.PathLike[str]) -> np.ndarray:
    """`read_exr` without the metadata: `[H, W, 3|4]` float32 pixels, any aspect ratio."""
    return read_exr(path)[0]


# ----------------------------------------------------------------------------------------------
# writing


def _as_channels(pixels: np.ndarray) -> dict[str, np.ndarray]:
    arr = np.asarray(pixels)
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 3, 4) or 0 in arr.shape[:2]:
        raise ShapeError(
            "pixels",
            arr.shape,
            "[H, W], [H, W, 1], [H, W, 3] or [H, W, 4] with H, W >= 1",
            "Pass Y, RGB or RGBA planes channels-last.",
        )
    if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise ShapeError("pixels", f"{arr.shape} {arr.dtype}", "a real-valued array")
    names = {1: "Y", 3: "RGB", 4: "RGBA"}[arr.shape[2]]
    return {n: arr[..., k] for k, n in enumerate(names)}


def _to_half(planes: dict[str, np.ndarray], overflow: HalfOverflowPolicy) -> dict[str, np.ndarray]:
    stacked = np.stack([p.astype(np.float32) for p in planes.values()], axis=-1)
    too_big = np.isfinite(stacked) & (np.abs(stacked) > HALF_MAX)
    count = int(too_big.sum())
    if count:
        peak = float(np.abs(stacked[too_big]).max())
        if overflow == "raise":
            raise HalfOverflowError(
                f"`pixels` holds {count} finite value(s) beyond the half-float range "
                f"(|max| = {peak:.6g} > {HALF_MAX:.0f}); they would become Inf. Write with "
                '`dtype="float32"`, pass `overflow="clamp"`, or scale the map down first.'
            )
        if overflow == "clamp":
            logger.warning(
                "clamping %d value(s) (|max| = %.6g) to +-%.0f for a half-float EXR",
                count,
                peak,
                HALF_MAX,
            )
            stacked = np.where(too_big, np.copysign(HALF_MAX, stacked), stacked)
        else:
            assert_never(overflow)
    half = stacked.astype(np.float16)
    return {n: np.ascontiguousarray(half[..., k]) for k, n in enumerate(planes)}


def _check_options(dtype: str, overflow: str, compression: str, envmap: str | None) -> None:
    checks = (
        ("dtype", dtype, ("float32", "half")),
        ("overflow", overflow, ("raise", "clamp")),
        ("compression", compression, get_args(ExrCompression)),
        ("envmap", envmap, (None, "latlong", "cube")),
    )
    for arg, value, allowed in checks:
        if value not in allowed:
            raise ValueError(f"`{arg}` must be one of {allowed}; got {value!r}.")


def write_exr(
    path: str | os.PathLike[str],
    pixels: np.ndarray,
    *,
    dtype: ExrDtype = "float32",
    overflow: HalfOverflowPolicy = "raise",
    compression: ExrCompression = "zip",
    envmap: Literal["latlong", "cube"] | None = None,
    attributes: dict[str, str] | None = None,
) -> None:
    """Write a single-part scan-line OpenEXR file, atomically.

    Args:
        path: destination (any suffix; `.exr` expected).
        pixels: `[H, W]` or `[H, W, 1]` (written as Y), `[H, W, 3]` (RGB) or `[H, W, 4]` (RGBA),
            float or integer; converted to `dtype`.
        dtype: "float32" (default, lossless for float32 input with a lossless compression) or
            "half" (16-bit float; max finite value 65504).
        overflow: for "half": "raise" (default) refuses finite values with |v| > 65504, "clamp"
            clamps them to +-65504 and logs a warning with the count. NaN and Inf are written
            as they are.
        compression: one of `ExrCompression`; default "zip" (lossless). "pxr24", "b44", "b44a",
            "dwaa" and "dwab" are lossy.
        envmap: write the standard `envmap` attribute ("latlong" or "cube"). Only set it for maps in
            OpenEXR's own layout (convention "openexr", corner-aligned lat-long, or the
            `gaffer_envmap.cube` face layout).
        attributes: extra string header attributes.

    Raises:
        ShapeError: `pixels` is not one of the shapes above.
        HalfOverflowError: `dtype="half"`, `overflow="raise"` and a finite |value| > 65504.
        ValueError: an unknown option value.
        EnvmapWriteError: the write failed; an existing file at `path` is left untouched.
    """
    _check_options(dtype, overflow, compression, envmap)
    planes = _as_channels(pixels)
    if dtype == "half":
        planes = _to_half(planes, overflow)
    else:
        planes = {n: np.ascontiguousarray(p, dtype=np.float32) for n, p in planes.items()}
    exr = _openexr()
    header: dict[str, object] = {
        "compression": getattr(exr, f"{compression.upper()}_COMPRESSION".replace("NONE", "NO")),
        "type": exr.scanlineimage,
    }
    if envmap is not None:
        header["envmap"] = (
            exr.Envmap.ENVMAP_LATLONG if envmap == "latlong" else exr.Envmap.ENVMAP_CUBE
        )
    for key, value in (attributes or {}).items():
        header[str(key)] = str(value)
    channels = {name: exr.Channel(name, plane) for name, plane in planes.items()}

    def _write(tmp: Path) -> None:
        exr.File(header, channels).write(str(tmp))

    atomic_write(path, _write)
