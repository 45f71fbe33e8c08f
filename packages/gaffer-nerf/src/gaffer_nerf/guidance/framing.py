"""Object-centred framing of the training views, as the relighting model was trained to see them.

A model trained on object-centred square crops (gaffer-tiny: the object's longer side spans 75% of
the square, the `object_fraction` of its `RelightPipeline.default_sampling`) relights a whole multi-view
frame, where the object may span 40% of it, much worse than its own crops (the full
method lost to SDS until the views were framed). So every path that shows a view to the model
(encoding the inputs, Stage 1's relit views, Stage 2's renders and SDS) crops it with the same
per-view square `ViewFraming.crop`, and Stage 1's relit crops go back into the frame with
`ViewFraming.paste`. The box is the one `gaffer_diffusion.preprocess.object_square` gives for
training and evaluation crops (same rule, same white outside the image), from the training alpha
or, for views without one, the fitted field's opacity.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.preprocess import ALPHA_THRESHOLD, object_square
from gaffer_nerf.errors import ConfigError, ShapeError

Box = tuple[int, int, int]
"""A square `(top, left, side)` in pixels of the view; it may reach past the image."""


@dataclass(frozen=True, kw_only=True)
class ViewFraming:
    """One square crop box per training view, and the views' size.

    Attributes:
        boxes: `(top, left, side)` of every view; a view without object pixels gets the centred
            square holding the whole frame.
        image_size: (H, W) of the views.
        object_fraction: the fraction of the side the object's longer extent spans.
    """

    boxes: tuple[Box, ...]
    image_size: tuple[int, int]
    object_fraction: float

    @property
    def num_views(self) -> int:
        """V."""
        return len(self.boxes)

    def crop(
        self, images: Float[Tensor, "B 3 H W"], views: Sequence[int], size: int
    ) -> Float[Tensor, "B 3 S S"]:
        """The boxes of `views` cut from `images` (white outside the frame), resized to `size`.

        Differentiable (padding, slicing and antialiased bilinear resizing), so Stage 2 and SDS
        reach the field through it.
        """
        if images.ndim != 4 or tuple(images.shape[2:]) != self.image_size:
            raise ShapeError(
                "images", tuple(images.shape), f"[B, 3, {self.image_size[0]}, {self.image_size[1]}]"
            )
        if len(views) != images.shape[0]:
            raise ShapeError("views", (len(views),), f"[{images.shape[0]}] (one index per image)")
        out = []
        for image, v in zip(images, views, strict=True):
            top, left, side = self.boxes[v]
            h, w = self.image_size
            pad = (max(-left, 0), max(left + side - w, 0), max(-top, 0), max(top + side - h, 0))
            padded = F.pad(image[None], pad, value=1.0)  # white, as the training crops
            y, x = top + pad[2], left + pad[0]
            square = padded[..., y : y + side, x : x + side]
            out.append(_resize(square, size))
        return torch.cat(out)

    def paste(
        self,
        crops: Float[Tensor, "B 3 S S"],
        views: Sequence[int],
        background: Float[Tensor, "B 3 H W"],
    ) -> Float[Tensor, "B 3 H W"]:
        """`crops` resized back to their boxes and laid over `background` (kept outside the boxes)."""
        if tuple(background.shape[2:]) != self.image_size:
            raise ShapeError(
                "background",
                tuple(background.shape),
                f"[B, 3, {self.image_size[0]}, {self.image_size[1]}]",
            )
        out = background.clone()
        h, w = self.image_size
        for i, v in enumerate(views):
            top, left, side = self.boxes[v]
            square = _resize(crops[i : i + 1].to(out), side)[0]
            y0, x0 = max(top, 0), max(left, 0)
            y1, x1 = min(top + side, h), min(left + side, w)
            out[i, :, y0:y1, x0:x1] = square[:, y0 - top : y1 - top, x0 - left : x1 - left]
        return out


def _resize(x: Tensor, size: int) -> Tensor:
    if tuple(x.shape[-2:]) == (size, size):
        return x
    return F.interpolate(x, size=(size, size), mode="bilinear", antialias=True, align_corners=False)


def frame_views(alpha: Float[Tensor, "V H W"], object_fraction: float) -> ViewFraming:
    """Per-view object-centred squares from `alpha` (coverage in [0, 1]) at `object_fraction`.

    Example:
        >>> import torch
        >>> a = torch.zeros(1, 64, 64)
        >>> a[0, 20:40, 10:30] = 1.0
        >>> frame_views(a, 0.5).boxes
        ((10, 0, 40),)
    """
    if not (isinstance(object_fraction, int | float) and 0.0 < object_fraction <= 1.0):
        raise ConfigError(
            f"`object_fraction` is {object_fraction!r}; expected a fraction in (0, 1] (gaffer-tiny: "
            "0.75), or 'whole' to show the model whole views."
        )
    if alpha.ndim != 3:
        raise ShapeError("alpha", tuple(alpha.shape), "[V, H, W]")
    v, h, w = (int(s) for s in alpha.shape)
    alpha_np = alpha.detach().float().cpu().numpy()
    covered = alpha_np > ALPHA_THRESHOLD
    side = max(h, w)
    whole: Box = ((h - side) // 2, (w - side) // 2, side)
    boxes = tuple(
        object_square(alpha_np[i], float(object_fraction)) if covered[i].any() else whole
        for i in range(v)
    )
    return ViewFraming(boxes=boxes, image_size=(h, w), object_fraction=float(object_fraction))
