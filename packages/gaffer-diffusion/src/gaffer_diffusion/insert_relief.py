"""The relief of an inserted object from its estimated normals: the front of `--shadow cycles`' proxy.

The paper's insertion adds a shadow with a shadow network (Neural Gaffer §4.1); `--shadow cycles`
renders it from a stand-in solid (`insert_shadow_cycles.proxy_scene`). The mask alone gives that solid
a circle's cross-section in every row; the learned normal estimator that feeds gaffer-tiny's hints
(`gaffer_diffusion.geometry.estimator`, gaffer-normals) also says how the visible surface turns. Here
the two are fused into one height field over the placed mask:

1. **Normals on the placed grid.** The estimator runs on the model's object-centred input (the framing
   it was trained on), its normals are carried to the photo through `PreparedPhoto.framing` and to the
   background through the same scale and shift as the object's pixels (`insert_geometry.place_object`).
2. **Integration.** Camera-frame normals `(nx, ny, nz)` (x right, y up, z toward the camera) give the
   surface's slope toward the camera, `dZ/dcol = -nx / nz` and `dZ/drow = ny / nz` (rows run down). A
   screened Poisson problem (as in Frankot and Chellappa's least-squares integration, restricted to the
   mask: no gradient is used across its outline) finds `Z` whose slopes best match those, plus a weak
   pull towards the mask's inflation `A` (the circle's half-chord of each row's run):
   `min sum_edges (Z_q - Z_p - g_pq)^2 + lam sum_p (Z_p - A_p)^2`, with `lam = 1 / width^2` for the
   mask's mean run width: the normals decide every detail finer than the object, the mask its overall
   thickness (normals alone cannot: a flat face says nothing of how far it stands in front of the
   outline). Solved by conjugate gradients in numpy; lengths are background pixels.
"""

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Bool, Float

from gaffer_diffusion.insert_geometry import ObjectExtent, Placement, place_object
from gaffer_diffusion.photo import PreparedPhoto, RelitObject
from gaffer_diffusion.preprocess import ALPHA_THRESHOLD

__all__ = [
    "MIN_NZ",
    "ObjectRelief",
    "estimated_relief",
    "inflation",
    "placed_normals",
    "relief_from_normals",
]

MIN_NZ = 0.2
"""Normals are tilted at most this far from the view (slope `<= sqrt(1 - MIN_NZ^2) / MIN_NZ`, about
4.9): at the outline the estimate turns edge-on and its slope is unbounded."""

_CG_TOL = 1e-6
_CG_MAX_ITER = 2000


@dataclass(frozen=True, kw_only=True)
class ObjectRelief:
    """The front surface of the placed object for the shadow's proxy.

    Attributes:
        height: `[h, w]` float64 over `PlacedObject.alpha`'s grid: how far each pixel of the object
            stands in front of the plane of its outline, toward the camera, in background pixels
            (0 outside the mask).
        source: what it came from, as the report says it (e.g. "gaffer-normals").
    """

    height: np.ndarray
    source: str


def inflation(mask: Bool[np.ndarray, "h w"]) -> Float[np.ndarray, "h w"]:
    """The mask's inflation: in each row, each run of the mask gets a circle's half-chord
    `sqrt(r^2 - (x - c)^2)` (centre `c`, radius `r` the run's half-length), in pixels.

    Example:
        >>> inflation(np.array([[0, 1, 1, 1, 0]], bool)).round(2).tolist()
        [[0.0, 1.12, 1.5, 1.12, 0.0]]
    """
    out = np.zeros(mask.shape, np.float64)
    for i, row in enumerate(np.asarray(mask, bool)):
        padded = np.concatenate([[False], row, [False]]).astype(np.int8)
        edges = np.flatnonzero(np.diff(padded))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            xs = np.arange(a, b) + 0.5
            c, r = (a + b) / 2.0, (b - a) / 2.0
            out[i, a:b] = np.sqrt(np.maximum(r**2 - (xs - c) ** 2, 0.0))
    return out


def relief_from_normals(
    normals: Float[np.ndarray, "h w 3"], mask: Bool[np.ndarray, "h w"]
) -> Float[np.ndarray, "h w"]:
    """The height toward the camera (pixels) whose slopes match `normals` inside `mask`, anchored
    weakly to the mask's `inflation` (the module docstring's screened Poisson problem).

    Args:
        normals: camera-frame unit normals (x right, y up, z toward the camera).
        mask: the object's pixels.

    Returns:
        `[h, w]` heights, `>= 0`, 0 outside `mask`.
    """
    m = np.asarray(mask, bool)
    h, w = m.shape
    out = np.zeros((h, w), np.float64)
    if not m.any():
        return out
    n = np.asarray(normals, np.float64)
    nz = np.maximum(n[..., 2], MIN_NZ)
    scale = np.sqrt(np.maximum(1.0 - nz**2, 0.0)) / np.maximum(np.hypot(n[..., 0], n[..., 1]), 1e-9)
    gx = -n[..., 0] * scale / nz  # dZ/dcol
    gy = n[..., 1] * scale / nz  # dZ/drow (rows run down, y up)
    anchor = inflation(m)
    runs = [int(v) for v in (anchor > 0).sum(1) if v]
    width = float(np.mean(runs)) if runs else 1.0
    lam = 1.0 / max(width, 1.0) ** 2
    # edges between neighbouring mask pixels, each with its target difference (the mean slope)
    right = m[:, :-1] & m[:, 1:]
    down = m[:-1, :] & m[1:, :]
    idx = -np.ones((h, w), np.int64)
    idx[m] = np.arange(int(m.sum()))
    ea = np.concatenate([idx[:, :-1][right], idx[:-1, :][down]])
    eb = np.concatenate([idx[:, 1:][right], idx[1:, :][down]])
    eg = np.concatenate(
        [
            ((gx[:, :-1] + gx[:, 1:]) / 2.0)[right],
            ((gy[:-1, :] + gy[1:, :]) / 2.0)[down],
        ]
    )
    count = len(idx[m])
    degree = np.bincount(ea, minlength=count) + np.bincount(eb, minlength=count)
    a_flat = anchor[m]

    def apply(z: np.ndarray) -> np.ndarray:  # (L + lam I) z, L the graph Laplacian of the edges
        lz = degree * z - np.bincount(ea, z[eb], count) - np.bincount(eb, z[ea], count)
        return lz + lam * z

    # right-hand side: D^T g + lam A (D the edge difference operator, z_b - z_a)
    rhs = np.bincount(eb, eg, count) - np.bincount(ea, eg, count) + lam * a_flat
    z = a_flat.copy()
    r = rhs - apply(z)
    p = r.copy()
    rr = float(r @ r)
    stop = _CG_TOL**2 * max(float(rhs @ rhs), 1e-30)
    for _ in range(_CG_MAX_ITER):
        if rr <= stop:
            break
        ap = apply(p)
        alpha = rr / float(p @ ap)
        z += alpha * p
        r -= alpha * ap
        rr_new = float(r @ r)
        p = r + (rr_new / rr) * p
        rr = rr_new
    out[m] = np.maximum(z, 0.0)
    return out


def placed_normals(
    prepared: PreparedPhoto,
    normals: Float[torch.Tensor, "3 S S"],
    box: tuple[int, int, int, int],
    extent: ObjectExtent,
    placement: Placement,
    background_hw: tuple[int, int],
) -> tuple[np.ndarray, np.ndarray]:
    """`normals` (over the model's input square) carried onto the placed object's grid: `([h, w, 3]
    unit normals, [h, w] coverage)` over the `PlacedObject.box` that `place_object` gives the
    `RelitObject` of photo box `box` (`(top, left, bottom, right)`, `RelitObject.box`)."""
    fr = prepared.framing
    t, l, b, r = box
    # photo pixel centre -> model pixel coordinate -> [-1, 1] (align_corners=False)
    ys = (np.arange(t, b) + 0.5 - fr.top) / fr.side_y * 2.0 - 1.0
    xs = (np.arange(l, r) + 0.5 - fr.left) / fr.side_x * 2.0 - 1.0
    grid = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None]), -1).astype(np.float32)
    photo_n = (
        F.grid_sample(
            normals.float()[None].cpu(),
            torch.from_numpy(grid)[None],
            mode="bilinear",
            padding_mode="border",
            align_corners=False,
        )[0]
        .permute(1, 2, 0)
        .numpy()
    )
    # place_object resamples colours in [0, 1]: normals go through as (n + 1) / 2
    carried = place_object(
        RelitObject(
            box=box,
            rgb=(photo_n + 1.0) / 2.0,
            alpha=np.asarray(prepared.alpha, np.float32)[t:b, l:r],
        ),
        extent,
        placement,
        background_hw,
    )
    n = carried.rgb.astype(np.float64) * 2.0 - 1.0
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-9)
    n[carried.alpha <= ALPHA_THRESHOLD] = (0.0, 0.0, 1.0)
    return n, carried.alpha


def estimated_relief(
    prepared: PreparedPhoto,
    box: tuple[int, int, int, int],
    extent: ObjectExtent,
    placement: Placement,
    background_hw: tuple[int, int],
    *,
    estimator_dir: str | None = None,
) -> ObjectRelief:
    """The placed object's relief from the learned normal estimator (the module docstring).

    Args:
        prepared: the object photo as the model sees it.
        box: the relit object's box in the photo (`RelitObject.box`): the relief is over the grid
            `place_object` gives it.
        extent, placement, background_hw: as given to `place_object` for the object itself.
        estimator_dir: an estimator folder (`NormalEstimator.save`); None: the shipped gaffer-normals.

    Raises:
        CheckpointNotFoundError: the estimator's manifest or weights are missing.
    """
    from gaffer_diffusion.geometry.estimator import (
        estimate_normals,
        load_normal_estimator,
        shipped_normal_estimator,
    )

    est = (
        shipped_normal_estimator()
        if estimator_dir is None
        else load_normal_estimator(estimator_dir)
    )
    inp = prepared.model_input
    normals = estimate_normals(est, inp.image.float(), inp.mask.float())[0]
    n, alpha = placed_normals(prepared, normals, box, extent, placement, background_hw)
    return ObjectRelief(
        height=relief_from_normals(n, alpha > ALPHA_THRESHOLD),
        source="gaffer-normals" if estimator_dir is None else str(estimator_dir),
    )
