"""Temporal flicker of a relit image sequence along a camera path, against its ground truth.

A relit orbit may change from frame to frame for two reasons: the object and its light really change
as the camera moves (the ground truth changes too), or the relighting is inconsistent between views
(flicker: a per-view brightness, colour or noise pattern that the ground truth does not have). Both are
frame-to-frame differences; flicker is the part of the relit sequence's difference that the ground
truth's does not explain:

    flicker = mean over consecutive pairs (t, t+1), channels and the pixels in both frames' masks of
              | (relit[t+1] - relit[t]) - (gt[t+1] - gt[t]) |

in [0, 1] image units (sRGB, like the PSNR inputs). Zero when the relit sequence changes exactly as
the ground truth does (a relit sequence equal to the ground truth up to a constant offset also scores
zero: that is a bias, which PSNR sees, not flicker). The ratio of temporal-difference energies,
mean (relit[t+1] - relit[t])^2 / mean (gt[t+1] - gt[t])^2 over the same pixels, says whether the
relit sequence moves more (> 1) or less (< 1) than the truth.
"""

from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_nerf.errors import ConfigError, ShapeError

ENERGY_EPS = 1e-10
"""Added to both energies of the ratio, so two static sequences have ratio 1 and never divide by 0."""


@dataclass(frozen=True, kw_only=True)
class FlickerReport:
    """Frame-to-frame consistency of a relit sequence against the ground-truth sequence.

    Attributes:
        flicker: mean |d relit - d gt| over pairs, channels and masked pixels (0 = no flicker).
        per_pair: the same for each consecutive pair (T - 1 values; T with `closed`).
        relit_energy: mean (d relit)^2 over the same pixels.
        gt_energy: mean (d gt)^2.
        energy_ratio: (relit_energy + eps) / (gt_energy + eps) (`ENERGY_EPS`).
        frames: T.
        masked_fraction: fraction of the pairs' pixels inside both frames' masks (1 without masks).
    """

    flicker: float
    per_pair: tuple[float, ...]
    relit_energy: float
    gt_energy: float
    energy_ratio: float
    frames: int
    masked_fraction: float


def temporal_flicker(
    relit: Tensor,
    ground_truth: Tensor,
    mask: Tensor | None = None,
    *,
    closed: bool = False,
) -> FlickerReport:
    """Flicker of `relit` along its frames, against `ground_truth` (see the module docstring).

    Args:
        relit: `[T, 3, H, W]` float, the relit sequence, in [0, 1], frames in camera-path order.
        ground_truth: `[T, 3, H, W]` float, the true sequence at the same cameras.
        mask: `[T, H, W]` per-frame coverage in [0, 1] (the ground truth's alpha); a pair counts the pixels by
            the product of its two frames' masks. None: every pixel.
        closed: the path is a full loop, so the last frame also pairs with the first.

    Returns:
        The `FlickerReport`.

    Raises:
        ShapeError: the sequences (or the mask) disagree in shape, or are not `[T, 3, H, W]`.
        ConfigError: fewer than 2 frames, or a mask that is empty on every pair.

    Example:
        >>> gt = torch.rand(4, 3, 8, 8)
        >>> temporal_flicker(gt + 0.1, gt).flicker < 1e-6  # an offset is a bias, not flicker
        True
    """
    if relit.ndim != 4 or relit.shape[1] != 3:
        raise ShapeError("relit", tuple(relit.shape), "[T, 3, H, W]")
    if tuple(ground_truth.shape) != tuple(relit.shape):
        raise ShapeError("ground_truth", tuple(ground_truth.shape), str(list(relit.shape)))
    t, _, h, w = relit.shape
    if mask is not None and tuple(mask.shape) != (t, h, w):
        raise ShapeError("mask", tuple(mask.shape), f"[{t}, {h}, {w}]")
    if t < 2:
        raise ConfigError(f"`relit` has {t} frame(s); flicker needs at least 2 along the path.")
    return _temporal_flicker(relit, ground_truth, mask, closed=closed)


def _temporal_flicker(
    relit: Float[Tensor, "T 3 H W"],
    ground_truth: Float[Tensor, "T 3 H W"],
    mask: Float[Tensor, "T H W"] | None,
    *,
    closed: bool,
) -> FlickerReport:
    """`temporal_flicker` once its shapes are checked (there with a ShapeError naming the argument;
    the public signature takes any tensor so that this error, not the test-time type hook's, speaks)."""
    t, _, h, w = relit.shape
    nxt = torch.roll(torch.arange(t), -1) if closed else torch.arange(1, t)
    cur = torch.arange(t) if closed else torch.arange(t - 1)
    x, y = relit.double(), ground_truth.double()
    d_relit, d_gt = x[nxt] - x[cur], y[nxt] - y[cur]  # [P, 3, H, W]
    if mask is None:
        weight = torch.ones(len(cur), 1, h, w, dtype=torch.float64)
    else:
        m = mask.double().clamp(0, 1)
        weight = (m[cur] * m[nxt]).unsqueeze(1)  # [P, 1, H, W]
    per_pair_w = weight.sum(dim=(1, 2, 3)) * 3
    total = float(per_pair_w.sum())
    if total <= 0:
        raise ConfigError(
            "`mask` leaves no pixel that is inside the object in two consecutive frames; pass the "
            "ground truth's alpha, or None to score every pixel."
        )
    gap = ((d_relit - d_gt).abs() * weight).sum(dim=(1, 2, 3))
    per_pair = tuple(float(g / n) if n > 0 else 0.0 for g, n in zip(gap, per_pair_w, strict=True))
    relit_energy = float((d_relit.square() * weight).sum()) / total
    gt_energy = float((d_gt.square() * weight).sum()) / total
    return FlickerReport(
        flicker=float(gap.sum()) / total,
        per_pair=per_pair,
        relit_energy=relit_energy,
        gt_energy=gt_energy,
        energy_ratio=(relit_energy + ENERGY_EPS) / (gt_energy + ENERGY_EPS),
        frames=t,
        masked_fraction=total / (3 * len(cur) * h * w),
    )
