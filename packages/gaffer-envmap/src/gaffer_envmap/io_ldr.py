"""8-bit PNG / JPEG reading through Pillow (PNGs are written by `gaffer_envmap.writers`).

Reading returns the stored (encoded) values as float32 in [0, 1]; `decode_to_linear` turns them
into linear radiance with an explicitly named encoding (env maps saved as PNG are usually sRGB; the
Neural Gaffer data uses a pure 2.2 power).
"""

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeGuard, assert_never, get_args

import numpy as np

from gaffer_envmap._exr_header import MAX_PIXELS
from gaffer_envmap.errors import EnvmapReadError

__all__ = ["LdrEncoding", "decode_to_linear", "read_ldr"]

LdrEncoding = Literal["srgb", "gamma2.2", "linear"]
"""How 8-bit values encode linear light.

- "srgb": the IEC 61966-2-1 piecewise curve (linear toe below 0.04045, 2.4 power above).
- "gamma2.2": a pure power, linear = value ** 2.2 (what Neural Gaffer's LDR maps use).
- "linear": values are linear already.
"""

_MODE_CONVERSION = {
    "1": "L",
    "P": "RGBA",
    "PA": "RGBA",
    "CMYK": "RGB",
    "YCbCr": "RGB",
    "LAB": "RGB",
}
_SIXTEEN_BIT_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I")


def _decode_pixels(img: Any, path: Path) -> tuple[np.ndarray, str]:
    """Pixels of an open PIL image as an array, after the mode conversions documented below."""
    width, height = img.size
    if width * height > MAX_PIXELS:
        raise EnvmapReadError(
            f"`path` {str(path)!r} declares {width} x {height} pixels, above the supported "
            f"{MAX_PIXELS}; the file is probably corrupt."
        )
    img.load()
    mode = img.mode
    if mode == "P" and "transparency" not in img.info:
        img, mode = img.convert("RGB"), "RGB"
    elif mode in _MODE_CONVERSION:
        img, mode = img.convert(_MODE_CONVERSION[mode]), _MODE_CONVERSION[mode]
    return np.array(img), mode


def _load(path: Path) -> tuple[np.ndarray, str]:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as img:  # closes the file on every path, errors included
            return _decode_pixels(img, path)
    except EnvmapReadError:
        raise
    except FileNotFoundError as exc:
        raise EnvmapReadError(f"`path` {str(path)!r} does not exist.") from exc
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError) as exc:
        raise EnvmapReadError(
            f"`path` {str(path)!r} could not be decoded as an image ({exc}); the file is "
            "probably truncated or corrupt."
        ) from exc


def read_ldr(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an 8-bit (or 16-bit grey) PNG / JPEG as stored values in [0, 1].

    Palette images are expanded to RGBA when they have transparency, to RGB otherwise; CMYK and
    YCbCr JPEGs are converted to RGB.

    Args:
        path: the file.

    Returns:
        `[H, W, C]` float32 in [0, 1], C = 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA);
        still encoded (see `decode_to_linear`).

    Raises:
        EnvmapReadError: missing, truncated, corrupt or too large file.
    """
    arr, mode = _load(Path(path))
    if mode in _SIXTEEN_BIT_MODES:
        scaled = arr.astype(np.float32) / 65535.0
    elif arr.dtype == np.uint8:
        scaled = arr.astype(np.float32) / 255.0
    else:
        raise EnvmapReadError(
            f"`path` {str(path)!r} has Pillow mode {mode!r} ({arr.dtype}); only 8-bit images and "
            "16-bit grey are supported. Store HDR data as .exr."
        )
    if scaled.ndim == 2:
        scaled = scaled[..., None]
    return np.ascontiguousarray(scaled)


if TYPE_CHECKING:
    _EncodingArg = LdrEncoding
else:  # at run time any str reaches `decode_to_linear`, which refuses an unknown one with a ValueError
    _EncodingArg = str


def _is_encoding(encoding: str) -> TypeGuard[LdrEncoding]:
    return encoding in get_args(LdrEncoding)


def decode_to_linear(values: np.ndarray, encoding: _EncodingArg = "srgb") -> np.ndarray:
    """Map encoded values in [0, 1] to linear light.

    Args:
        values: `[...]` float array of encoded values (alpha must be split off first).
        encoding: "srgb" (default), "gamma2.2" or "linear".

    Returns:
        float32 array of the same shape.

    Raises:
        ValueError: unknown `encoding`.

    Example:
        >>> decode_to_linear(np.array([0.0, 0.5, 1.0]), "gamma2.2").astype(float).round(4).tolist()
        [0.0, 0.2176, 1.0]
    """
    if not _is_encoding(encoding):
        raise ValueError(f"`encoding` must be 'srgb', 'gamma2.2' or 'linear'; got {encoding!r}.")
    v = np.asarray(values, dtype=np.float32)
    if encoding == "srgb":
        return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4).astype(np.float32)
    if encoding == "gamma2.2":
        return np.power(np.maximum(v, 0.0), 2.2).astype(np.float32)
    if encoding == "linear":
        return v
    assert_never(encoding)
