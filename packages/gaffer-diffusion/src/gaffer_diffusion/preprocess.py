"""Input-image preprocessing as in the authors' real-image demo.

1. Object mask from the image's alpha channel or a separate mask file (no segmentation model: none can be
   downloaded here, so an image without alpha and without a mask is an error).
2. Crop to the mask's bounding box.
3. Pad to a square so that the object's longer side spans `object_fraction` (75%) of it, centred.
4. Composite on white with the (straight) alpha: rgb * a + (1 - a).
5. Resize to `size` x `size` (PIL bicubic, antialiased).

`compat="neural-gaffer"` (`prepare_object_image_neural_gaffer`) follows the authors' real-image script
step by step instead (our reading of its steps, docs/encodings.md, which lists them).
"""

from dataclasses import dataclass
from pathlib import Path
from typing import assert_never

import numpy as np
import torch
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from gaffer_diffusion import _choices
from gaffer_diffusion.errors import InputValueError

# the render readers live in the one image module; importable from here as before
from gaffer_diffusion.images import crop_square as crop_square
from gaffer_diffusion.images import load_rgba_on_white as load_rgba_on_white
from gaffer_diffusion.images import read_alpha as read_alpha
from gaffer_envmap.writers import quantize

ALPHA_THRESHOLD = 0.5
"""Alpha above this counts as object when computing the bounding box."""

PrepareCompat = _choices.PrepareCompat
"""How an object photo becomes the model's input: ours (`prepare_object_image`) or the authors' steps."""

NG_THUMBNAIL = 512
"""The authors shrink the photo to fit 512 x 512 (PIL `thumbnail`, LANCZOS) before segmenting it."""

NG_OBJECT_FRACTION = 0.75
"""Their framing: square side = int(longest box side / 0.75)."""


@dataclass(frozen=True, kw_only=True)
class PreparedImage:
    """A preprocessed object image.

    Attributes:
        image: `[1, 3, S, S]` float32 sRGB in [0, 1], object on white.
        mask: `[1, 1, S, S]` float32 alpha in [0, 1].
        bbox: (top, left, bottom, right) of the object in the source image, pixels.
    """

    image: Float[Tensor, "1 3 S S"]
    mask: Float[Tensor, "1 1 S S"]
    bbox: tuple[int, int, int, int]


def prepare_object_image(
    rgb: np.ndarray,
    alpha: np.ndarray,
    *,
    size: int = 256,
    object_fraction: float = 0.75,
) -> PreparedImage:
    """Crop, pad, composite on white and resize an object image (see the module docstring).

    Args:
        rgb: `[H, W, 3]` uint8 or float in [0, 1], sRGB, straight (not premultiplied) colour.
        alpha: `[H, W]` uint8 or float in [0, 1].
        size: output side length (the model resolution).
        object_fraction: fraction of the output side spanned by the object's longer side.

    Raises:
        InputValueError: on an empty mask, mismatched shapes or a bad `object_fraction`.
    """
    rgb_f = _to_unit(rgb, "rgb")
    a = _to_unit(alpha, "alpha")
    if rgb_f.ndim != 3 or rgb_f.shape[2] != 3:
        raise InputValueError(f"`rgb` has shape {rgb_f.shape}, expected [H, W, 3].")
    if a.shape != rgb_f.shape[:2]:
        raise InputValueError(
            f"`alpha` / mask has shape {a.shape}, expected the image's {rgb_f.shape[:2]}."
        )
    if not 0.0 < object_fraction <= 1.0:
        raise InputValueError(f"`object_fraction` is {object_fraction}; expected (0, 1].")
    ys, xs = np.nonzero(a > ALPHA_THRESHOLD)
    if ys.size == 0:
        raise InputValueError(
            "The object mask is empty (no alpha / mask value above 0.5): nothing to relight. Check "
            "the mask file or the image's alpha channel."
        )
    top, bottom, left, right = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    crop_rgb = rgb_f[top:bottom, left:right]
    crop_a = a[top:bottom, left:right]
    h, w = crop_a.shape
    side = max(int(np.ceil(max(h, w) / object_fraction)), 1)
    canvas_rgb = np.ones((side, side, 3), np.float32)
    canvas_a = np.zeros((side, side), np.float32)
    oy, ox = (side - h) // 2, (side - w) // 2
    # composite on white with straight alpha
    canvas_rgb[oy : oy + h, ox : ox + w] = crop_rgb * crop_a[..., None] + (1.0 - crop_a[..., None])
    canvas_a[oy : oy + h, ox : ox + w] = crop_a
    img = Image.fromarray(quantize(canvas_rgb)).resize((size, size), Image.Resampling.BICUBIC)
    msk = Image.fromarray(quantize(canvas_a)).resize((size, size), Image.Resampling.BICUBIC)
    image = torch.from_numpy(np.asarray(img, np.float32) / 255.0).permute(2, 0, 1)[None]
    mask = torch.from_numpy(np.asarray(msk, np.float32) / 255.0)[None, None]
    return PreparedImage(image=image.contiguous(), mask=mask, bbox=(top, left, bottom, right))


def _to_unit(arr: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(arr)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    a = a.astype(np.float32)
    if not np.isfinite(a).all():
        raise InputValueError(f"`{name}` holds NaN/Inf values.")
    return np.clip(a, 0.0, 1.0)


def prepare_object_image_neural_gaffer(
    rgb: np.ndarray, alpha: np.ndarray, *, size: int = 256
) -> PreparedImage:
    """The authors' real-image preparation (our reading of their script), with the given alpha as
    SAM's mask.

    1. Shrink to fit 512 x 512 (PIL `thumbnail`, LANCZOS; never enlarges). The photo is RGB there and
       the mask is made afterwards on the shrunk photo; a mask given here goes through the same
       `thumbnail` call as an 8-bit grey image (our reading: they have no full-size mask).
    2. The tight box of alpha > 0 (h rows, w columns).
    3. side = int(max(w, h) / 0.75) (truncation), a transparent black `side x side` RGBA square, the box
       copied in at row side//2 - h//2, column side//2 - w//2 (row/column offsets of an array slice).
    4. The RGBA square resized to `size` with PIL LANCZOS (PIL resamples RGBA premultiplied).
    5. Composited on white in float64, rgb * a + (1 - a) with both in [0, 1], and truncated to uint8
       (`astype(uint8)` of v * 255).

    Args:
        rgb: `[H, W, 3]` uint8 sRGB, straight colour.
        alpha: `[H, W]` uint8 alpha or mask (white = object).
        size: output side (their 256).

    Returns:
        `PreparedImage` with the uint8 result / 255, the resized alpha of step 4 as `mask`, and `bbox` in
        the thumbnail's pixels.

    Raises:
        InputValueError: on non-uint8 input, mismatched shapes or an empty mask.
    """
    rgb_u8, a_u8 = np.asarray(rgb), np.asarray(alpha)
    if rgb_u8.dtype != np.uint8 or a_u8.dtype != np.uint8:
        raise InputValueError(
            f"`rgb` / `alpha` are {rgb_u8.dtype} / {a_u8.dtype}; the authors' steps work on 8-bit "
            "images: pass uint8 arrays (or read the file with `load_object_image`)."
        )
    if rgb_u8.ndim != 3 or rgb_u8.shape[2] != 3:
        raise InputValueError(f"`rgb` has shape {rgb_u8.shape}, expected [H, W, 3].")
    if a_u8.shape != rgb_u8.shape[:2]:
        raise InputValueError(
            f"`alpha` / mask has shape {a_u8.shape}, expected the image's {rgb_u8.shape[:2]}."
        )
    if size < 1:
        raise InputValueError(f"`size` is {size}; expected >= 1 (their 256).")
    lanczos = Image.Resampling.LANCZOS
    photo, mask = Image.fromarray(rgb_u8, "RGB"), Image.fromarray(a_u8, "L")
    photo.thumbnail((NG_THUMBNAIL, NG_THUMBNAIL), lanczos)
    mask.thumbnail((NG_THUMBNAIL, NG_THUMBNAIL), lanczos)
    rgba = np.dstack([np.asarray(photo), np.asarray(mask)])  # [h', w', 4] uint8
    ys, xs = np.nonzero(rgba[..., 3] > 0)  # their box: every pixel with alpha > 0
    if ys.size == 0:
        raise InputValueError(
            "The object mask is empty (no alpha / mask value above 0): nothing to relight. Check "
            "the mask file or the image's alpha channel."
        )
    top, left = int(ys.min()), int(xs.min())
    h, w = int(ys.max()) + 1 - top, int(xs.max()) + 1 - left
    side = int(max(w, h) / NG_OBJECT_FRACTION)
    square = np.zeros((side, side, 4), np.uint8)  # transparent black
    row, col = side // 2 - h // 2, side // 2 - w // 2
    square[row : row + h, col : col + w] = rgba[top : top + h, left : left + w]
    small = np.asarray(Image.fromarray(square, "RGBA").resize((size, size), lanczos)) / 255.0
    a = small[..., 3:]
    on_white = ((small[..., :3] * a + (1.0 - a)) * 255).astype(np.uint8)  # truncation, as theirs
    image = torch.from_numpy(on_white.astype(np.float32) / 255.0).permute(2, 0, 1)[None]
    mask_t = torch.from_numpy(a[..., 0].astype(np.float32))[None, None]
    return PreparedImage(image=image.contiguous(), mask=mask_t, bbox=(top, left, top + h, left + w))


def load_object_image(
    path: str | Path,
    *,
    mask_path: str | Path | None = None,
    size: int = 256,
    object_fraction: float = 0.75,
    compat: PrepareCompat = "default",
) -> PreparedImage:
    """Read an image (PNG/JPG/...) and preprocess it; the mask comes from `mask_path` or the alpha.

    Args:
        path: the photo.
        mask_path: a grey mask (white = object) for an image without alpha.
        size: output side.
        object_fraction: framing of `compat="default"` (the authors' is fixed at 0.75).
        compat: "default" (`prepare_object_image`) or "neural-gaffer"
            (`prepare_object_image_neural_gaffer`, the authors' steps).

    Raises:
        InputValueError: when the image has no alpha channel and no `mask_path` is given, or a file
            cannot be read.
    """
    p = Path(path)
    try:
        with Image.open(p) as im:
            has_alpha = im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info
            rgba = np.asarray(im.convert("RGBA"))
    except (OSError, ValueError) as exc:
        raise InputValueError(f"Could not read the image `{p}`: {exc}") from exc
    if mask_path is not None:
        try:
            with Image.open(mask_path) as m:
                alpha = np.asarray(m.convert("L"))
        except (OSError, ValueError) as exc:
            raise InputValueError(f"Could not read the mask `{mask_path}`: {exc}") from exc
    elif has_alpha:
        alpha = rgba[..., 3]
    else:
        raise InputValueError(
            f"`{p}` has no alpha channel and no mask was given. Neural Gaffer relights a segmented "
            "object: pass `--mask MASK.png` (white = object), or save the image as an RGBA PNG with the "
            "background transparent. No segmentation model is downloaded automatically."
        )
    match compat:
        case "default":
            return prepare_object_image(
                rgba[..., :3], alpha, size=size, object_fraction=object_fraction
            )
        case "neural-gaffer":
            return prepare_object_image_neural_gaffer(
                np.ascontiguousarray(rgba[..., :3]), np.ascontiguousarray(alpha), size=size
            )
        case _:
            assert_never(compat)


def object_square(alpha: np.ndarray, object_fraction: float) -> tuple[int, int, int]:
    """The square `(top, left, side)` centred on the object whose side is its longer extent /
    `object_fraction` (the same framing as `prepare_object_image`); it may reach past the image.

    Raises:
        InputValueError: on an empty mask or a bad `object_fraction`.
    """
    if not 0.0 < object_fraction <= 1.0:
        raise InputValueError(f"`object_fraction` is {object_fraction}; expected (0, 1].")
    ys, xs = np.nonzero(_to_unit(alpha, "alpha") > ALPHA_THRESHOLD)
    if ys.size == 0:
        raise InputValueError("The object mask is empty (no alpha above 0.5): nothing to crop to.")
    top, bottom, left, right = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    side = max(int(np.ceil(max(bottom - top, right - left) / object_fraction)), 1)
    return top + (bottom - top - side) // 2, left + (right - left - side) // 2, side
