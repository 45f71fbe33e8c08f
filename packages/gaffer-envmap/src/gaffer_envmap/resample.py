"""Solid-angle-exact (conservative) resampling between lat-long grids.

Solid angle is uniform in (phi, z = cos theta), so the area-overlap weights between two lat-long grids
factor into a matrix over rows (overlap in z) and one over columns (overlap in u). Each output pixel is the
Omega-weighted mean of the input area it covers, so total power sum(L * Omega) is preserved exactly for
any pair of sizes (first-order conservative remapping, as SCRIP / CDO `remapcon` do for climate grids).
Integer factors take a reshape-and-sum fast path. Reference: ../shared/reference/envmap-conventions.md 4.2.
"""

import numpy as np
import torch
from torch import Tensor

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ShapeError


def _row_overlap(h_in: int, h_out: int) -> np.ndarray:
    """`[h_out, h_in]`: weight of input row i in output row o (rows of an Omega-weighted mean)."""
    z_in = np.cos(np.arange(h_in + 1) * np.pi / h_in)  # decreasing from 1 to -1
    z_out = np.cos(np.arange(h_out + 1) * np.pi / h_out)
    hi = np.minimum(z_out[:-1, None], z_in[None, :-1])
    lo = np.maximum(z_out[1:, None], z_in[None, 1:])
    overlap = np.clip(hi - lo, 0.0, None)
    return overlap / (z_out[:-1] - z_out[1:])[:, None]


def _col_overlap(w_in: int, w_out: int) -> np.ndarray:
    """`[w_out, w_in]`: weight of input column j in output column o (both grids start at u = 0)."""
    u_in = np.arange(w_in + 1) / w_in
    u_out = np.arange(w_out + 1) / w_out
    hi = np.minimum(u_out[1:, None], u_in[None, 1:])
    lo = np.maximum(u_out[:-1, None], u_in[None, :-1])
    return np.clip(hi - lo, 0.0, None) * w_out


def resize_conservative_torch(radiance: Tensor, height: int, width: int | None = None) -> Tensor:
    """Conservative resize of `[..., He, We, 3]` maps to `[..., height, width, 3]` (width default 2*height).

    Exact power for any sizes; float64 accumulation for the weights, result in the input dtype.
    """
    if radiance.ndim < 3 or radiance.shape[-1] != 3:
        raise ShapeError("radiance", tuple(radiance.shape), "[..., He, We, 3]")
    h_in, w_in = radiance.shape[-3], radiance.shape[-2]
    width = 2 * height if width is None else width
    if height < 1 or width < 1:
        raise ShapeError("height/width", (height, width), "positive sizes")
    if (h_in, w_in) == (height, width):
        return radiance
    x = radiance.double()
    lead = x.shape[:-3]
    x = x.reshape(-1, h_in, w_in, 3)
    if h_in != height:
        if h_in % height == 0:
            k = h_in // height
            z_in = torch.cos(
                torch.arange(h_in + 1, dtype=torch.float64, device=x.device) * torch.pi / h_in
            )
            dz = (z_in[:-1] - z_in[1:]).reshape(height, k)
            x = (x.reshape(-1, height, k, w_in, 3) * dz[None, :, :, None, None]).sum(2)
            x = x / dz.sum(1)[None, :, None, None]
        else:
            wr = torch.from_numpy(_row_overlap(h_in, height)).to(x.device)
            x = torch.einsum("oi,niwc->nowc", wr, x)
    if w_in != width:
        if w_in % width == 0:
            x = x.reshape(x.shape[0], height, width, w_in // width, 3).mean(3)
        else:
            wc = torch.from_numpy(_col_overlap(w_in, width)).to(x.device)
            x = torch.einsum("oj,nhjc->nhoc", wc, x)
    return x.reshape(*lead, height, width, 3).to(radiance.dtype)


def resize_conservative(env: EnvironmentMap, height: int) -> EnvironmentMap:
    """Resize a map to `[height, 2*height]`, preserving total power to float round-off (about 1e-7).

    Example:
        >>> import numpy as np
        >>> from gaffer_envmap.stats import total_power
        >>> env = EnvironmentMap(radiance_linear=np.random.default_rng(1).random((64, 128, 3), np.float32))
        >>> small = resize_conservative(env, 24)
        >>> bool(np.allclose(total_power(small), total_power(env), rtol=1e-6))
        True
    """
    out = resize_conservative_torch(torch.from_numpy(np.array(env.radiance_linear)), int(height))
    return env.with_radiance(out.numpy())
