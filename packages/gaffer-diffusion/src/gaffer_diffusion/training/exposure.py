"""Exposure and tint augmentation of target lightings: scale a target's map and its render together.

Rendering is linear in the light, channel by channel (Cycles renders RGB; every material here acts on
each channel alone): the render of an object under a map whose channel c is scaled by `k_c` is its
render with channel c scaled by `k_c`, in linear radiance. With the Standard view transform (what
gaffer-tiny's data uses) the PNG is the sRGB encoding of that radiance clipped to [0, 1]. So a target
render can be re-exposed and re-tinted exactly, up to 8-bit rounding, by decoding its object pixels
to linear, scaling each channel and re-encoding with the same clip, while its environment map is
scaled the same way. For `k_c >= 1` this is exact even where the render clipped (a clipped pixel stays
clipped); for `k_c < 1` only where nothing clipped, so a darkening draw on a channel with clipped object
pixels is turned into the brightening one of the same size (`exposure_gains`).

Why (measured on gaffer-tiny 0.3's validation split, 250 pairs): over the object, the log of the
relit/input brightness ratio follows the true ratio with a slope of only 0.51, and the relit colour
(chromaticity of the mean linear colour) does not follow the target's at all (slope -0.02; its
chromaticity error is 0.169 against the input's 0.138). A small model trained on a few dozen lightings
keeps the input's level and colour. Drawing each target's level and colour cast at random makes them a
function of the target map, as physics has it. Not in the paper (`DataConfig.target_exposure_stops`
and `target_tint_stops` = 0, the defaults, turn it off).
"""

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.images import linear_to_srgb, srgb_to_linear

__all__ = ["CLIPPED_LEVEL", "exposure_gains", "reexpose_on_white"]

CLIPPED_LEVEL = 254.5 / 255.0
"""An 8-bit sRGB value at or above this is taken as clipped by the render."""

_ALPHA_MIN = 1e-3


def _object_colour(
    image_on_white: Float[Tensor, "3 S S"], alpha: Float[Tensor, "1 S S"]
) -> Float[Tensor, "3 S S"]:
    """The straight sRGB colour under the alpha (c = a rgb + 1 - a inverted; 0 where a ~ 0)."""
    a = alpha.clamp_min(_ALPHA_MIN)
    rgb = (image_on_white - (1.0 - alpha)) / a
    return torch.where(alpha > _ALPHA_MIN, rgb, torch.zeros_like(rgb)).clamp(0.0, 1.0)


def exposure_gains(
    stops: Float[Tensor, "3"], image_on_white: Float[Tensor, "3 S S"], alpha: Float[Tensor, "1 S S"]
) -> Float[Tensor, "3"]:
    """Per-channel gains `2^stops`, with `2^|stops_c|` where a draw darkens a channel that clipped.

    Args:
        stops: the drawn change of each channel, in stops.
        image_on_white: the target render composited on white, sRGB in [0, 1].
        alpha: its alpha in [0, 1].

    Example:
        >>> img, a = torch.full((3, 4, 4), 0.5), torch.ones(1, 4, 4)
        >>> exposure_gains(torch.tensor([-1.0, 0.0, 1.0]), img, a).tolist()
        [0.5, 1.0, 2.0]
        >>> img[0] = 1.0  # red clipped: darkening it would need the lost values
        >>> exposure_gains(torch.tensor([-1.0, -1.0, 1.0]), img, a).tolist()
        [2.0, 0.5, 2.0]
    """
    rgb = _object_colour(image_on_white, alpha)
    clipped = ((rgb >= CLIPPED_LEVEL) & (alpha > 0.5)).flatten(1).any(dim=1)
    stops = torch.where(clipped & (stops < 0), -stops, stops)
    return torch.exp2(stops.to(torch.float32))


def reexpose_on_white(
    image_on_white: Float[Tensor, "3 S S"], alpha: Float[Tensor, "1 S S"], gains: Float[Tensor, "3"]
) -> Float[Tensor, "3 S S"]:
    """The same render under its lighting with channel c times `gains[c]`, composited on white again.

    Args:
        image_on_white: sRGB render on white in [0, 1] (`load_rgba_on_white`).
        alpha: its alpha.
        gains: the lighting's per-channel gains (> 0).

    Example:
        >>> a = torch.ones(1, 2, 2)
        >>> out = reexpose_on_white(torch.full((3, 2, 2), 0.5), a, torch.full((3,), 2.0))
        >>> round(float(out[0, 0, 0]), 3)  # sRGB 0.5 is linear 0.214; x2 = 0.428 -> sRGB 0.686
        0.686
    """
    if not bool(torch.isfinite(gains).all() and (gains > 0).all()):
        raise ValueError(f"exposure gains {gains.tolist()}; need finite > 0")
    rgb = _object_colour(image_on_white, alpha)
    out = linear_to_srgb(srgb_to_linear(rgb) * gains.to(rgb.dtype)[:, None, None])
    return (out * alpha + (1.0 - alpha)).clamp(0.0, 1.0)
