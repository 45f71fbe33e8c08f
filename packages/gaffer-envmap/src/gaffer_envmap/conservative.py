"""Power-exact rotation into the camera frame: bilinear lookup, corrected by its own adjoint (torch).

Notation (reference section 4): source texels i with solid angle Omega_i and radiance L_i; output
sub-samples s (an ss x ss split of each output pixel o) with solid angle w_s; b(s, i) the bilinear weight
of texel i in the lookup of sample s (seam wrapped, poles crossed). A plain pull,
out_o = sum_{s in o} w_s / Omega_o sum_i b(s, i) L_i, keeps constants but not power: texel i is read with
total weight C_i = sum_s w_s b(s, i) (the adjoint of the lookup applied to the sample weights), which is
not Omega_i, and a sub-pixel sun can fall between samples. Reading L'_i = L_i Omega_i / C_i instead makes
sum_o Omega_o out_o = sum_i C_i L'_i = sum_i Omega_i L_i: power is exact per channel, for every map and
pose, with a gain that is local to each texel (no global rescale).

The gain is smooth only where every texel is read by a few samples, so the source is first resized
conservatively (`resample`) to at most the sample density (`conservative_height`), and near the source
poles, where a row's texels are narrower than the sample spacing, runs of k texels in a row are merged
into one group (their mean; same row, same Omega, so also power-exact) that shares one gain
(`row_groups`). A group no sample reads (possible only in corner cases) is splatted whole into the output
pixel that holds its centre, so no power is ever dropped.

This module is the general path (any device, `outer` and `zip` pairing) and the reference twin of the
fused CPU kernel in `_fast_cpu.py`.
"""

import math
from functools import lru_cache

import numpy as np
import torch
from torch import Tensor

from gaffer_envmap.conventions import row_solid_angle


def conservative_height(src_height: int, out_height: int, out_width: int, ss: int) -> int:
    """Source height the conservative filter reads: halve (power-exactly) while the source has more texels
    per radian than the output has sub-samples, in either angle (never upsamples)."""
    ssv, ssu = sub_samples(out_height, out_width, ss)
    limit = max(1, int(DENSITY * min(ssv * out_height, (ssu * out_width) // 2)))
    h = src_height
    while h % 2 == 0 and h > max(limit, 1):
        h //= 2
    return h


DENSITY = 1.0
"""Source rows per sub-sample row kept by the pre-downsample."""


@lru_cache(maxsize=64)
def row_groups(height: int, width: int, spacing_rad: float) -> tuple[int, ...]:
    """Texels merged per cell in each source row: the power of two dividing `width` nearest (in log scale)
    to making a cell `spacing_rad` wide, never below 1 (so 1 away from the poles). Callers pass the
    sample spacing times `GROUP_SPAN`."""
    out = []
    for r in range(height):
        wide = 2 * math.pi / width * math.sin((r + 0.5) * math.pi / height)
        k = 1
        # Nearest power of two in log space: a row within sqrt(2) of the gap width stays whole (rows near
        # the equator are a hair narrower than the gaps; merging them would blur suns by a texel).
        while k * wide * math.sqrt(2) < spacing_rad and width % (2 * k) == 0:
            k *= 2
        out.append(k)
    return tuple(out)


GROUP_SPAN = 1.5
"""A pole group spans at least this many sample gaps. Wider groups even out how often each cell is read,
so the gain Omega_g / C_g ripples less on flat maps, but they move a sun towards its group's centre; where
the source is as dense as the samples (64 x 128 from 128 x 256 at supersample 2) a span above sqrt(2)
merges equatorial texels in pairs too. Measured at supersample 2 (flat-map ripple max / rms over
3 random poses, sun error over 6 random 1.5-degree suns, power exact to 5e-8 in every case):
span 1: 256 x 256 from 512 x 256 8.9% / 0.62%, 64 x 128 from 128 x 256 13% / 1.9%, sun 0.61 degrees;
span 1.5: 6.3% / 0.58%, 6.6% / 1.1%, 0.64 degrees; span 2: 5.9% / 0.51%, 6.1% / 1.0%, 0.64 degrees.
Halving the source instead (pre-downsample to half the sample density) left the 64 x 128 ripple at 9.9%."""


def sub_samples(out_height: int, out_width: int, ss: int) -> tuple[int, int]:
    """Sub-samples per output pixel (rows, columns): `ss` rows and as many columns as keep them square at
    the camera equator (a 256 x 256 map has pixels twice as wide as tall, so twice the columns)."""
    return ss, max(1, round(ss * 2 * out_height / out_width))


def sample_spacing(out_height: int, out_width: int, ss: int) -> float:
    """Largest angular gap between neighbouring output sub-samples (at the camera equator)."""
    ssv, ssu = sub_samples(out_height, out_width, ss)
    return max(math.pi / (out_height * ssv), 2 * math.pi / (out_width * ssu))


@lru_cache(maxsize=16)
def _sample_grid(height: int, width: int, ssv: int, ssu: int) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame sub-sample directions `[h ssv, w ssu, 3]` and absolute weights w_s `[h ssv]` (float64)."""
    hs, ws = height * ssv, width * ssu
    theta = math.pi * (np.arange(hs) + 0.5) / hs
    phi = 2 * math.pi * (0.5 - (np.arange(ws) + 0.5) / ws)
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    dirs = np.stack(
        [st * np.cos(phi)[None], np.broadcast_to(ct, (hs, ws)), -st * np.sin(phi)[None]], -1
    )
    return dirs, row_solid_angle(hs, ws)


@lru_cache(maxsize=64)
def reduced_grid(height: int, width: int, spacing_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """Cells per row `[He]` (width / k_r) and each row's first cell in the flat cell list `[He]` (int64)."""
    cells = np.array([width // k for k in row_groups(height, width, spacing_rad)], np.int64)
    return cells, np.concatenate([[0], np.cumsum(cells)[:-1]])


def cell_means(src: Tensor, cells: np.ndarray) -> Tensor:
    """`[N, He, We, C]` -> `[N, sum(cells), C]`: each row's runs of We / cells[r] texels averaged (same row,
    same Omega: power-exact)."""
    n, _, we, c = src.shape
    rows = [
        src[:, r] if k == we else src[:, r].reshape(n, int(k), we // int(k), c).mean(dim=2)
        for r, k in enumerate(cells)
    ]
    return torch.cat(rows, dim=1)


def cell_taps(coords: Tensor, cells: np.ndarray, starts: np.ndarray) -> list[tuple[Tensor, Tensor]]:
    """Bilinear taps on the reduced grid: four (flat cell index, weight) pairs of `[N, S]` for source
    coordinates `coords` `[N, S, 2]` (u in [0, 1), v in [0, 1]). Rows interpolate in v; each row
    interpolates in u at its own cell width; the row beyond a pole is the edge row turned by half."""
    he = len(cells)
    n_t = torch.from_numpy(cells).to(coords.device)
    s_t = torch.from_numpy(starts).to(coords.device)
    u, v = coords[..., 0], coords[..., 1]
    y = v * he - 0.5
    y0 = y.floor()
    fy = y - y0
    taps = []
    for dy, wy in ((0, 1 - fy), (1, fy)):
        ry = y0.long() + dy
        across = (ry < 0) | (ry >= he)
        ry = ry.clamp(0, he - 1)
        ur = torch.where(across, u + 0.5, u)
        nr = n_t[ry]
        x = ur * nr - 0.5
        x0 = x.floor()
        fx = x - x0
        j0 = torch.remainder(x0.long(), nr)
        j1 = torch.remainder(j0 + 1, nr)
        taps.append((s_t[ry] + j0, wy * (1 - fx)))
        taps.append((s_t[ry] + j1, wy * fx))
    return taps


def lookup_coords(m: Tensor, out_h: int, out_w: int, ssv: int, ssu: int) -> Tensor:
    """Source (u, v) `[P, h ssv, w ssu, 2]` of the sub-samples for lookup rotations `m` `[P, 3, 3]`
    (d_world = m^T d_cam; Blender convention), float64."""
    dirs, _ = _sample_grid(out_h, out_w, ssv, ssu)
    d = torch.from_numpy(dirs).to(m.device) @ m.to(torch.float64)[:, None]  # row vectors: d_cam @ m
    u = torch.remainder(0.5 - torch.atan2(d[..., 1], d[..., 0]) / (2 * math.pi), 1.0)
    v = torch.acos(d[..., 2].clamp(-1.0, 1.0)) / math.pi
    return torch.stack([u, v], dim=-1)


def rotate_conservative(
    src: Tensor, m: Tensor, out_h: int, out_w: int, ss: int
) -> tuple[Tensor, Tensor]:
    """Power-exact rotation of paired maps `src` `[N, He, We, 3]` (already at `conservative_height`) by
    lookup rotations `m` `[N, 3, 3]`. Returns channels-first radiance `[N, 3, h, w]` (input dtype) and the
    per-cell gains Omega_g / C_g `[N, cells]` (float64; 0 where a cell is splatted instead)."""
    n, he, we, _ = src.shape
    dev = src.device
    ssv, ssu = sub_samples(out_h, out_w, ss)
    cells, starts = reduced_grid(he, we, GROUP_SPAN * sample_spacing(out_h, out_w, ss))
    lbar = cell_means(src.to(torch.float64), cells)  # [N, G, 3]
    coords = lookup_coords(m, out_h, out_w, ssv, ssu).reshape(n, -1, 2)
    taps = cell_taps(coords, cells, starts)
    _, w_rows = _sample_grid(out_h, out_w, ssv, ssu)
    w_s = torch.from_numpy(np.repeat(w_rows, out_w * ssu)).to(dev)  # [S]
    # Adjoint of the lookup: C_g = sum_s w_s b(s, g).
    cover = torch.zeros((n, lbar.shape[1]), dtype=torch.float64, device=dev)
    for idx, wt in taps:
        cover.scatter_add_(1, idx, wt * w_s)
    omega_rows = row_solid_angle(he, we) * (we / cells)  # a cell's solid angle, per row
    omega = torch.from_numpy(np.repeat(omega_rows, cells)).to(dev)[None]  # [1, G]
    read = cover > 0
    gain = torch.where(read, omega / torch.where(read, cover, 1.0), 0.0)  # [N, G]
    corrected = lbar * gain[..., None]
    vals = torch.zeros((n, coords.shape[1], 3), dtype=torch.float64, device=dev)
    for idx, wt in taps:
        vals += torch.gather(corrected, 1, idx[..., None].expand(-1, -1, 3)) * wt[..., None]
    # Output pixel o = sum over its sub-samples of w_s / Omega_o times the sample value.
    vals = (vals * w_s[None, :, None]).reshape(n, out_h, ssv, out_w, ssu, 3).sum(dim=(2, 4))
    om_out = torch.from_numpy(row_solid_angle(out_h, out_w)).to(dev)
    out = vals / om_out[None, :, None, None]
    lost = ~read & (lbar != 0).any(dim=-1)
    if bool(lost.any()):
        out = _splat_unread(out, lbar, lost, m, om_out, cells, starts, omega[0])
    return out.permute(0, 3, 1, 2).to(src.dtype), gain


def _splat_unread(
    out: Tensor,
    lbar: Tensor,
    lost: Tensor,
    m: Tensor,
    om_out: Tensor,
    cells: np.ndarray,
    starts: np.ndarray,
    omega: Tensor,
) -> Tensor:
    """Deposit the power L_g Omega_g of every cell no sample reads into the output pixel holding its
    centre (`out` `[N, h, w, 3]` float64; `lost` `[N, G]`)."""
    n, out_h, out_w, _ = out.shape
    he = len(cells)
    b, g = torch.nonzero(lost, as_tuple=True)
    row_of = torch.from_numpy(np.repeat(np.arange(he), cells)).to(out.device)
    r = row_of[g]
    j = g - torch.from_numpy(starts).to(out.device)[r]
    theta = (r.double() + 0.5) * math.pi / he
    phi = 2 * math.pi * (0.5 - (j.double() + 0.5) / torch.from_numpy(cells).to(out.device)[r])
    d_world = torch.stack(
        [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], dim=-1
    )  # Blender convention
    d_cam = (m.to(torch.float64)[b] @ d_world[..., None])[..., 0]  # d_cam = m d_world
    tc = torch.acos(d_cam[:, 1].clamp(-1, 1))
    uc = torch.remainder(0.5 - torch.atan2(-d_cam[:, 2], d_cam[:, 0]) / (2 * math.pi), 1.0)
    ro = (tc / math.pi * out_h).long().clamp(0, out_h - 1)
    co = (uc * out_w).long() % out_w
    power = lbar[b, g] * (omega[g] / om_out[ro])[:, None]
    flat = out.reshape(n * out_h * out_w, 3).clone()
    flat.index_add_(0, (b * out_h + ro) * out_w + co, power)
    return flat.reshape(out.shape)
