"""Detail transfer: a low-resolution relit prediction applied to the full-resolution photo.

The model sees the object at its own resolution (64-256 px), but the photo can be 4000 px wide. Upsampling
the model's output loses the photo's texture, print and edges. Instead we take from the model only what it
is good at, the *change of shading*, and apply that change to the full-resolution input:

1. ratio `rho = (relit_lin + eps) / (input_lin + eps)` in linear light at the model's resolution, per
   channel, as a log, clamped to `[-log RATIO_MAX, log RATIO_MAX]`;
2. pixels near the object's silhouette (blended with the white backdrop in the model's input) get no
   weight; their ratio is filled in from the object's interior by push-pull;
3. the log ratio is resampled bilinearly to the photo's pixels and then steered by the full-resolution
   photo with a guided filter (He, Sun and Tang, "Guided Image Filtering", ECCV 2010 / TPAMI 2013), so that
   a change of light that stops at an edge in the photo stops there at full resolution too;
4. `out_lin = photo_lin * exp(log rho)`: where the light changes smoothly, the photo's detail survives.

The box filter is an integral-image mean, O(pixels) for any radius.
"""

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float

EPS_LINEAR = 1e-2
"""Added to both sides of the shading ratio (linear light): keeps black pixels from giving wild ratios."""

RATIO_MAX = 16.0
"""The shading ratio is clamped to [1/16, 16] (4 stops either way)."""

GUIDED_EPS = 1e-3
"""Guided-filter regulariser for a guide in [0, 1]: edges with a contrast well above sqrt(1e-3) ~ 0.03
steer the ratio; flatter texture does not."""

WEIGHT_THRESHOLD = 0.95
"""Model-resolution mask value above which a pixel's ratio is trusted (not blended with the backdrop)."""


def srgb_to_linear(rgb_srgb: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB decoding of values in [0, 1] (float32)."""
    c = np.clip(np.asarray(rgb_srgb, np.float32), 0.0, 1.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def linear_to_srgb(rgb_linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding, clipped to [0, 1] (float32)."""
    c = np.clip(np.asarray(rgb_linear, np.float32), 0.0, 1.0)
    return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055).astype(np.float32)


def box_mean(x: Float[np.ndarray, "H W *C"], radius: int) -> Float[np.ndarray, "H W *C"]:
    """Mean over the `(2 radius + 1)^2` window around each pixel, windows cut at the image border.

    An integral image, so the cost does not grow with `radius`.

    Example:
        >>> box_mean(np.ones((4, 5), np.float32), 2).tolist()[0][0]
        1.0
    """
    x = np.asarray(x, np.float64)
    h, w = x.shape[:2]

    def _axis_sum(a: np.ndarray, axis: int, n: int) -> np.ndarray:
        c = np.cumsum(a, axis=axis)
        pad = [(0, 0)] * a.ndim
        pad[axis] = (1, 0)
        c = np.pad(c, pad)
        hi = np.minimum(np.arange(n) + radius + 1, n)
        lo = np.maximum(np.arange(n) - radius, 0)
        return np.take(c, hi, axis=axis) - np.take(c, lo, axis=axis)

    s = _axis_sum(_axis_sum(x, 0, h), 1, w)
    ones = np.ones((h, w))
    count = _axis_sum(_axis_sum(ones, 0, h), 1, w)
    if x.ndim == 3:
        count = count[..., None]
    return (s / count).astype(np.float32)


def guided_filter(
    guide: Float[np.ndarray, "H W"],
    src: Float[np.ndarray, "H W *C"],
    radius: int,
    eps: float = GUIDED_EPS,
) -> Float[np.ndarray, "H W *C"]:
    """He et al.'s guided filter with a grey guide: `q = mean(a) I + mean(b)` with, per window,
    `a = cov(I, p) / (var(I) + eps)` and `b = mean(p) - a mean(I)`.

    Args:
        guide: `[H, W]` grey guide image `I` (e.g. the photo's luma, in [0, 1]).
        src: `[H, W]` or `[H, W, C]` image `p` to filter (each channel against the same guide).
        radius: window radius in pixels (>= 1).
        eps: regulariser; larger smooths more.

    Returns:
        The filtered image, float32, the shape of `src`.

    Example:
        >>> g = np.tile(np.linspace(0, 1, 8, dtype=np.float32), (8, 1))
        >>> bool(np.allclose(guided_filter(g, g, 2, 1e-6), g, atol=1e-3))
        True
    """
    i = np.asarray(guide, np.float32)
    p = np.asarray(src, np.float32)
    ie = i[..., None] if p.ndim == 3 else i
    mean_i = box_mean(ie, radius)
    mean_p = box_mean(p, radius)
    cov_ip = box_mean(ie * p, radius) - mean_i * mean_p
    var_i = box_mean(ie * ie, radius) - mean_i * mean_i
    a = cov_ip / (var_i + eps)
    b = mean_p - a * mean_i
    return (box_mean(a, radius) * ie + box_mean(b, radius)).astype(np.float32)


def push_pull_fill(
    values: Float[torch.Tensor, "C H W"], weight: Float[torch.Tensor, "H W"]
) -> Float[torch.Tensor, "C H W"]:
    """Fill pixels of zero `weight` from their weighted neighbourhood, coarse to fine (push-pull).

    Pixels of weight 1 keep their value; fractional weights blend ("over") with the coarser estimate.
    """
    levels: list[tuple[torch.Tensor, torch.Tensor]] = []
    v, w = values * weight[None], weight[None].clone()  # premultiplied
    while True:
        levels.append((v, w))
        if min(v.shape[-2:]) <= 1:
            break
        v = F.avg_pool2d(v[None], 2, ceil_mode=True)[0]
        w = F.avg_pool2d(w[None], 2, ceil_mode=True)[0]
    v, w = levels[-1]
    est = torch.where(w > 0, v / w.clamp_min(1e-12), torch.zeros_like(v))
    for v, w in reversed(levels[:-1]):
        up = F.interpolate(est[None], size=v.shape[-2:], mode="bilinear", align_corners=False)[0]
        wc = w.clamp(0.0, 1.0)
        est = torch.where(wc > 0, v / wc.clamp_min(1e-12), up) * wc + up * (1.0 - wc)
    return est


def log_shading_ratio(
    input_srgb: Float[np.ndarray, "S S 3"],
    relit_srgb: Float[np.ndarray, "S S 3"],
    mask: Float[np.ndarray, "S S"],
) -> Float[np.ndarray, "S S 3"]:
    """Per-channel log of the linear-light shading ratio relit / input, filled outside the object.

    Args:
        input_srgb: the model's input (object on white), sRGB in [0, 1].
        relit_srgb: the model's prediction, sRGB in [0, 1].
        mask: the model-resolution object mask in [0, 1].

    Returns:
        `[S, S, 3]` float32 `log rho`, clamped to +-log(RATIO_MAX).
    """
    lin_in, lin_out = srgb_to_linear(input_srgb), srgb_to_linear(relit_srgb)
    log_rho = np.log((lin_out + EPS_LINEAR) / (lin_in + EPS_LINEAR))
    log_rho = np.clip(log_rho, -np.log(RATIO_MAX), np.log(RATIO_MAX))
    weight = (np.asarray(mask, np.float32) > WEIGHT_THRESHOLD).astype(np.float32)
    if weight.sum() == 0:  # a tiny or thin object: trust every pixel that is mostly object
        weight = (np.asarray(mask, np.float32) > 0.5).astype(np.float32)
    filled = push_pull_fill(
        torch.from_numpy(np.ascontiguousarray(log_rho.transpose(2, 0, 1))),
        torch.from_numpy(weight),
    )
    return filled.permute(1, 2, 0).numpy().astype(np.float32)


def luma(rgb_srgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luma of an sRGB image `[..., 3]` (the guide of the guided filter)."""
    return (
        np.asarray(rgb_srgb, np.float32) @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    ).astype(np.float32)


def apply_shading(
    photo_srgb: Float[np.ndarray, "H W 3"],
    log_rho_up: Float[np.ndarray, "H W 3"],
    *,
    radius: int,
    eps: float = GUIDED_EPS,
) -> Float[np.ndarray, "H W 3"]:
    """Steer an upsampled log ratio by the photo (guided filter) and apply it in linear light.

    Args:
        photo_srgb: the full-resolution photo (or a crop of it), sRGB in [0, 1].
        log_rho_up: the log shading ratio resampled to the same pixels.
        radius: guided-filter radius in photo pixels (about the photo/model scale; 0 skips the filter).
        eps: guided-filter regulariser.

    Returns:
        The relit photo pixels, sRGB in [0, 1], float32.
    """
    if radius > 0:
        log_rho_up = guided_filter(luma(photo_srgb), log_rho_up, radius, eps)
    lim = float(np.log(RATIO_MAX))
    rho = np.exp(np.clip(log_rho_up, -lim, lim))
    return linear_to_srgb(srgb_to_linear(photo_srgb) * rho)
