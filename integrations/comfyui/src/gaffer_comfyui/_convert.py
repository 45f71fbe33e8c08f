"""ComfyUI tensors in and out: IMAGE `[B, H, W, C]` float in 0..1 (C = 3, or 4 with alpha) and MASK
`[B, H, W]` (or `[H, W]`) float in 0..1, checked at the node boundary with one-line errors.

Mask senses: ComfyUI's LoadImage gives a MASK that is 1 where the picture is *transparent* (the
inverted alpha), while segmentation nodes give 1 on the object. The relight nodes never guess: their
`mask_sense` input says which one a MASK is, and their MASK output uses the same sense.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, assert_never, get_args

import numpy as np
import torch

from .errors import NodeInputError

MaskSense = Literal["white = object", "black = object (LoadImage)"]
"""`white = object`: 1 on the object (segmenters, painted masks). `black = object (LoadImage)`: 0 on
the object, 1 around it, as ComfyUI's LoadImage derives MASK from a transparent PNG (1 - alpha)."""

MASK_SENSES: tuple[str, ...] = get_args(MaskSense)

ALPHA_THRESHOLD = 0.5
"""An object pixel is one above this (gaffer-diffusion's photo mask threshold)."""

SURROUNDING_RIM = 0.95
"""A mask whose object covers this share of the picture's border pixels surrounds the frame: it is
the background, the mask read in the wrong sense (an object photo shows its object inside the frame)."""


@dataclass(frozen=True, kw_only=True)
class PhotoItem:
    """One picture of an IMAGE batch as gaffer-diffusion reads a photo.

    Attributes:
        photo: `gaffer_diffusion.photo.Photo` (sRGB, `rgb_u8` the bytes written back outside the mask).
        alpha: `[H, W]` float32 object mask in [0, 1], 1 on the object.
    """

    photo: object
    alpha: np.ndarray


def check_image(node: str, name: str, image: object, *, min_side: int = 8) -> torch.Tensor:
    """`image` as a `[B, H, W, C]` float32 CPU tensor, C in (3, 4), values finite in [0, 1].

    Raises:
        NodeInputError: not a tensor, another shape, or values outside [0, 1].
    """
    if not isinstance(image, torch.Tensor):
        raise NodeInputError(
            f"{node}: `{name}` is a {type(image).__name__}, not an IMAGE tensor; connect an IMAGE "
            "output (e.g. LoadImage)."
        )
    t = image[None] if image.ndim == 3 else image
    if t.ndim != 4 or t.shape[-1] not in (3, 4) or min(t.shape[:3]) < 1:
        raise NodeInputError(
            f"{node}: `{name}` has shape {tuple(image.shape)}; expected an IMAGE [B, H, W, 3] (or 4 "
            "channels with alpha)."
        )
    if min(t.shape[1:3]) < min_side:
        raise NodeInputError(
            f"{node}: `{name}` is {t.shape[2]}x{t.shape[1]} pixels; give a picture at least "
            f"{min_side}x{min_side}."
        )
    t = t.detach().to("cpu", torch.float32)
    if not bool(torch.isfinite(t).all()) or float(t.min()) < -1e-6 or float(t.max()) > 1 + 1e-6:
        raise NodeInputError(
            f"{node}: `{name}` holds values outside [0, 1] (or NaN); ComfyUI IMAGEs are floats in 0..1: "
            "clamp or normalise it first."
        )
    return t.clamp(0.0, 1.0)


def object_alphas(
    node: str,
    image: torch.Tensor,
    mask: object,
    sense: str,
) -> list[np.ndarray]:
    """One `[H, W]` float32 object mask (1 on the object) per picture of `image` `[B, H, W, C]`.

    From `mask` read in `sense`; without a mask, the IMAGE's own alpha (4 channels), else an
    estimate by GrabCut (gaffer-diffusion's `--mask auto` fallback; needs OpenCV).

    Raises:
        NodeInputError: an unknown `mask_sense`, a mask of another size or batch, or one that marks
            no object or the whole picture (the message says to flip `mask_sense`).
    """
    if sense not in MASK_SENSES:
        raise NodeInputError(
            f"{node}: `mask_sense` is {sense!r}; choose one of {list(MASK_SENSES)}."
        )
    b, h, w, c = image.shape
    if mask is None:
        if c == 4:
            alphas = [image[i, ..., 3].numpy().astype(np.float32) for i in range(b)]
            for i, a in enumerate(alphas):
                _check_object(node, "the alpha channel of `image`", a, i, "connect a `mask`")
            return alphas
        return [_estimate(node, image[i, ..., :3]) for i in range(b)]
    m = _mask_tensor(node, mask, b, h, w)
    out = []
    for i in range(b):
        mi = m[i if m.shape[0] == b else 0].numpy().astype(np.float32)
        match sense:
            case "white = object":
                alpha = mi
            case "black = object (LoadImage)":
                alpha = (1.0 - mi).astype(np.float32)
            case _:
                assert_never(sense)  # type: ignore[arg-type]
        _check_object(node, f"`mask` read as {sense!r}", alpha, i, "flip `mask_sense`")
        out.append(alpha)
    return out


def _mask_tensor(node: str, mask: object, b: int, h: int, w: int) -> torch.Tensor:
    if not isinstance(mask, torch.Tensor):
        raise NodeInputError(
            f"{node}: `mask` is a {type(mask).__name__}, not a MASK tensor; connect a MASK output."
        )
    m = mask[None] if mask.ndim == 2 else mask
    if m.ndim != 3 or m.shape[1:] != (h, w) or m.shape[0] not in (1, b):
        hint = (
            " LoadImage gives an empty 64x64 MASK for a picture without alpha: disconnect `mask` "
            "(then the object is estimated) or connect a real one."
            if tuple(m.shape[-2:]) == (64, 64)
            else " Resize the mask to the image, or pick the matching batch item."
        )
        raise NodeInputError(
            f"{node}: `mask` has shape {tuple(mask.shape)}; expected [{b} or 1, {h}, {w}] like "
            f"`image` [{b}, {h}, {w}, C].{hint}"
        )
    m = m.detach().to("cpu", torch.float32)
    if not bool(torch.isfinite(m).all()) or float(m.min()) < -1e-6 or float(m.max()) > 1 + 1e-6:
        raise NodeInputError(
            f"{node}: `mask` holds values outside [0, 1] (or NaN); clamp it first."
        )
    return m.clamp(0.0, 1.0)


def _check_object(node: str, what: str, alpha: np.ndarray, index: int, fix: str) -> None:
    fg = alpha > ALPHA_THRESHOLD
    item = f" (batch item {index})" if index else ""
    if not fg.any():
        raise NodeInputError(
            f"{node}: {what}{item} marks no object (no value above 0.5); {fix} if the object is "
            "the other colour, or connect a mask that covers it."
        )
    if fg.all():
        raise NodeInputError(
            f"{node}: {what}{item} marks the whole picture as the object; {fix} if the object is "
            "the other colour, or connect a mask with background around the object."
        )
    rim = np.concatenate([fg[0], fg[-1], fg[1:-1, 0], fg[1:-1, -1]])
    if rim.mean() >= SURROUNDING_RIM:
        raise NodeInputError(
            f"{node}: {what}{item} marks the picture's whole border as the object, which would "
            f"surround the frame: the mask is inverted; {fix}."
        )


def _estimate(node: str, rgb: torch.Tensor) -> np.ndarray:
    """GrabCut's object mask of one `[H, W, 3]` picture (gaffer-diffusion's `--mask auto`)."""
    from gaffer_diffusion.automask import grabcut_mask
    from gaffer_diffusion.errors import InputValueError, MissingDependencyError

    rgb_u8 = np.round(rgb.numpy() * 255.0).astype(np.uint8)
    try:
        alpha = grabcut_mask(rgb_u8)
    except MissingDependencyError as exc:
        raise NodeInputError(
            f"{node}: no `mask` is connected and `image` has no alpha, so the object would be "
            'estimated, which needs OpenCV: connect a `mask`, or pip install "gaffer-diffusion[photo]".'
        ) from exc
    except InputValueError as exc:
        raise NodeInputError(
            f"{node}: no `mask` is connected and GrabCut (the classical fallback) found no object in "
            "`image`: connect a `mask` (e.g. from a segmentation node)."
        ) from exc
    alpha = np.asarray(alpha, np.float32)
    _check_object(node, "the estimated (GrabCut) mask", alpha, 0, "connect a `mask`")
    return alpha


def photo_items(
    node: str, image: torch.Tensor, alphas: list[np.ndarray], name: str
) -> list[PhotoItem]:
    """Each picture of `image` `[B, H, W, C]` as a gaffer-diffusion `Photo`, with its object mask.

    `rgb` keeps the IMAGE's float values (an 8-bit picture from LoadImage is `u8 / 255` exactly, as
    `gaffer_diffusion.photo.read_photo` reads it); `rgb_u8` are their rounded bytes.
    """
    from gaffer_diffusion.photo import Photo

    items = []
    for i in range(image.shape[0]):
        rgb = np.ascontiguousarray(image[i, ..., :3].numpy(), dtype=np.float32)
        photo = Photo(
            rgb_u8=np.round(rgb * 255.0).astype(np.uint8),
            rgb=rgb,
            alpha=None,
            alpha_u8=None,
            path=Path(f"<{node} {name}[{i}]>"),
        )
        items.append(PhotoItem(photo=photo, alpha=alphas[i]))
    return items


def to_image(frames: list[np.ndarray]) -> torch.Tensor:
    """`[B, H, W, 3]` float32 IMAGE in 0..1 from uint8 `[H, W, 3 or 4]` frames (alpha dropped)."""
    arr = np.stack([np.asarray(f)[..., :3] for f in frames]).astype(np.float32) / 255.0
    return torch.from_numpy(arr)


def to_mask(alphas: list[np.ndarray], sense: str) -> torch.Tensor:
    """`[B, H, W]` float32 MASK from object masks (1 on the object), in `sense`."""
    m = torch.from_numpy(np.stack([np.asarray(a, np.float32) for a in alphas]))
    return m if sense == "white = object" else 1.0 - m


def preview_image(rgb_u8: np.ndarray) -> torch.Tensor:
    """`[1, H, W, 3]` IMAGE of one uint8 picture."""
    return to_image([rgb_u8])
