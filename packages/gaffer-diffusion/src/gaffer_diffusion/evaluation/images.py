"""Reading the pairs' images as they are scored: on white, optionally cropped, at the model's size
(`gaffer_diffusion.images`, the same reader as training); masks; `quantize_8bit` is re-exported."""

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from torch import Tensor

from gaffer_diffusion.errors import DatasetError
from gaffer_diffusion.evaluation.records import EvalPair
from gaffer_diffusion.images import crop_square, load_rgba_on_white, read_alpha
from gaffer_diffusion.images import quantize_8bit as quantize_8bit  # its home before
from gaffer_diffusion.preprocess import object_square


def read_rgba_on_white(
    path: Path, size: int, box: tuple[int, int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """`[S, S, 3]` float32 sRGB composited on white and `[S, S]` alpha, both in [0, 1], read by the
    same loader as training (`gaffer_diffusion.preprocess.load_rgba_on_white`), optionally cropped."""
    try:
        rgb, alpha = load_rgba_on_white(path, size, None, box)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the render `{path}`: {exc}. Re-render it.") from exc
    return rgb.permute(1, 2, 0).numpy(), alpha[0].numpy()


def pair_crop_box(pair: "EvalPair", object_fraction: float | None) -> tuple[int, int, int] | None:
    """The object-centred square of `pair`'s view (from its mask, else the input's alpha), or None."""
    if object_fraction is None:
        return None
    src = pair.mask if pair.mask is not None else pair.input_image
    try:
        return object_square(read_alpha(src), object_fraction)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the mask `{src}`: {exc}. Re-render it.") from exc


def read_mask(path: Path, size: int, box: tuple[int, int, int] | None = None) -> np.ndarray:
    """`[S, S]` float32 mask in [0, 1] from a greyscale (or any) image file, optionally cropped to
    `box`, resized to `size` (bilinear, antialiased, as the images)."""
    try:
        with Image.open(path) as im:
            m = np.asarray(im.convert("L"), np.float32)[..., None] / 255.0
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the mask `{path}`: {exc}. Re-render it.") from exc
    if box is not None:
        m = crop_square(m, box, 0.0)
    t = torch.from_numpy(np.ascontiguousarray(m)).permute(2, 0, 1)[None]
    if tuple(t.shape[2:]) != (size, size):
        t = F.interpolate(
            t, size=(size, size), mode="bilinear", align_corners=False, antialias=True
        )
    return t[0, 0].clamp(0, 1).numpy()


def _to_chw(arrs: list[np.ndarray]) -> Tensor:
    t = torch.from_numpy(np.stack(arrs))
    return t.permute(0, 3, 1, 2).contiguous() if t.ndim == 4 else t[:, None].contiguous()
