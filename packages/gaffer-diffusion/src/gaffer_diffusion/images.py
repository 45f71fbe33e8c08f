"""Reading renders on white, and the typed 8-bit grid of `gaffer_envmap.writers` for `[C, H, W]` tensors.

- Reading: `load_rgba_on_white` is the one reader of rendered views for training, evaluation and the
  demo (one resize: bilinear, antialiased, colour and alpha together), with `crop_square` and
  `read_alpha` for the object-centred framing. `gaffer_diffusion.preprocess` re-exports all three.
- Transfer: `srgb_to_linear` / `linear_to_srgb`, the sRGB curve (IEC 61966-2-1) on tensors, for
  every place that moves display images into linear light and back (hints, exposure augmentation,
  the log-linear residual target).
- Quantising: `quantize_8bit` snaps float images to the 8-bit grid (as a PNG round trip would) and
  `to_uint8` turns a `[C, H, W]` tensor into the `[H, W, C]` uint8 array a PNG holds; both are
  `gaffer_envmap.writers`' one rounding rule (nearest level, ties to even), which also writes every
  PNG, GIF and MP4 (atomically).
"""

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from gaffer_envmap.writers import quantize, quantize_float


def srgb_to_linear(x: Tensor) -> Tensor:
    """Display sRGB in [0, 1] (clipped) to linear light, the piecewise sRGB curve.

    Example:
        >>> import torch
        >>> round(float(srgb_to_linear(torch.tensor(0.5))), 4)
        0.214
    """
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.04045, x / 12.92, ((x + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(x: Tensor) -> Tensor:
    """Linear light (clipped to [0, 1]) to display sRGB, the inverse of `srgb_to_linear`."""
    x = x.clamp(0.0, 1.0)
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x ** (1 / 2.4) - 0.055)


def quantize_8bit(images: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 3 H W"]:
    """Round to the 8-bit grid, as writing and re-reading a PNG would (the authors score PNGs).

    Example:
        >>> import torch
        >>> x = quantize_8bit(torch.full((1, 3, 1, 1), 0.301))
        >>> round(float(x[0, 0, 0, 0]) * 255, 3)
        77.0
    """
    return quantize_float(images)


def to_uint8(image: Float[Tensor, "C H W"]) -> np.ndarray:
    """`[C, H, W]` float in [0, 1] -> `[H, W, C]` uint8 on the grid of `quantize_8bit`.

    Example:
        >>> import torch
        >>> to_uint8(torch.tensor([[[0.301, 1.5]]])).tolist()
        [[[77], [255]]]
    """
    return quantize(image.permute(1, 2, 0))


def crop_square(arr: np.ndarray, box: tuple[int, int, int], fill: float) -> np.ndarray:
    """`arr[top:top+side, left:left+side]` of an `[H, W, C]` array, padded with `fill` outside it."""
    top, left, side = box
    out = np.full((side, side, arr.shape[2]), fill, dtype=arr.dtype)
    y0, x0 = max(top, 0), max(left, 0)
    y1, x1 = min(top + side, arr.shape[0]), min(left + side, arr.shape[1])
    if y1 > y0 and x1 > x0:
        out[y0 - top : y1 - top, x0 - left : x1 - left] = arr[y0:y1, x0:x1]
    return out


def load_rgba_on_white(
    path: Path,
    size: int,
    alpha_path: Path | None = None,
    box: tuple[int, int, int] | None = None,
) -> tuple[Float[Tensor, "3 S S"], Float[Tensor, "1 S S"]]:
    """An sRGB PNG (straight alpha) composited on white and its alpha, cropped and resized to `size`.

    The one reader of rendered views for training, evaluation and the demo, so all of them see the
    same pixels: optional square crop `box` (`object_square`; transparent outside the image), straight
    alpha over white in sRGB (as the authors do), then bilinear antialiased resizing of colour and
    alpha together.

    Args:
        path: RGBA (or RGB) 8-bit image.
        size: output side length.
        alpha_path: a separate 8-bit mask used when the image has no alpha channel.
        box: `(top, left, side)` crop in the image's pixels, or None for the whole image.

    Returns:
        `[3, size, size]` colour and `[1, size, size]` alpha, float32 in [0, 1].

    Raises:
        OSError: unreadable or truncated file (PIL's errors).
        ValueError: unusable image data.
    """

    with Image.open(path) as im:
        im.load()
        rgba = np.asarray(im.convert("RGBA"), dtype=np.float32) / 255.0
        has_alpha = im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info
    rgb, alpha = rgba[..., :3], rgba[..., 3:4]
    if not has_alpha and alpha_path is not None:
        with Image.open(alpha_path) as m:
            m.load()
            alpha = np.asarray(m.convert("L"), dtype=np.float32)[..., None] / 255.0
        if alpha.shape[:2] != rgb.shape[:2]:
            raise ValueError(f"mask {alpha_path} has size {alpha.shape[:2]}, image {rgb.shape[:2]}")
    # straight alpha over white: c = a * rgb + (1 - a) * 1   (in sRGB, as the authors do)
    arr = np.concatenate([rgb * alpha + (1.0 - alpha), alpha], axis=-1)
    if box is not None:
        arr = np.concatenate(
            [crop_square(arr[..., :3], box, 1.0), crop_square(arr[..., 3:], box, 0.0)], -1
        )
    out = torch.from_numpy(np.ascontiguousarray(arr)).permute(2, 0, 1)  # [4, h, w]
    if tuple(out.shape[1:]) != (size, size):
        out = F.interpolate(
            out[None], size=(size, size), mode="bilinear", align_corners=False, antialias=True
        )[0]
    out = out.clamp(0.0, 1.0)
    return out[:3].contiguous(), out[3:].contiguous()


def read_alpha(path: Path) -> np.ndarray:
    """`[H, W]` float32 alpha in [0, 1] of an RGBA image, or the grey values of a mask file."""
    with Image.open(path) as im:
        im.load()
        if im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info:
            return np.asarray(im.convert("RGBA"), np.float32)[..., 3] / 255.0
        return np.asarray(im.convert("L"), np.float32) / 255.0
