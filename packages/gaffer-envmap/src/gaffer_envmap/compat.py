"""The authors' preprocessing, reproduced bit for bit (`compat="neural-gaffer"`).

The released checkpoint was trained on maps made this way, so it should be fed maps made this way
(reference section 4, steps 1-7):

1. output grid the size of the source, elevation +pi/2 (top) .. -pi/2 and azimuth +pi (left) .. -pi at
   pixel centres; d_local = (cos phi cos theta, sin phi cos theta, sin theta);
2. d_world = d_local (A R) as row vectors, A = [[1,0,0],[0,0,-1],[0,1,0]], R the w2c rotation;
   their turntable frame k of N multiplies on the right by Rz(-2 pi k / N) (their inference script;
   docs/encodings.md), so `spin_deg = D` here is their frame k = D / 360 * N: the light turns by -D
   about world up (clockwise seen from above), the OPPOSITE sense of the default mode's `spin_deg`;
3. theta' = arccos(d_z) - 1e-6 (their offset; docs/encodings.md), phi' = atan2(d_y, d_x),
   grid x = -phi'/pi, y = 2 theta'/pi - 1, clamped to
   +-(1 - 1e-7); bilinear `grid_sample`, align_corners=True, zero padding (no seam wrap, identity off by up
   to half a pixel);
4. LDR = clip(E, 0, 1) ** (1/2.2); HDR = log1p(10 E) / max(log1p(10 E)) over the rotated map, clipped;
5. floor(v * 255) to uint8, then PIL bilinear resize of the 2:1 map to size x size (an anisotropic squash).

What we keep from our own code: the direction grid is cached per size and the rotation is batched; both
change speed only, not a single output value (tests compare against `testing.reference_neural_gaffer`,
which follows the reference step by step in torch). Against an independent numpy re-implementation of the
same steps (benchmarks/bench_envmap_preprocess.py) a handful of uint8 values differ by one (3 of 6.3M in
the committed run, made before the script took the theta offset too), from float rounding in
the bilinear weights and the power at a uint8 boundary; none differs by more. With the offset, the twin
and this module differ in about 1 of 200K values of a 512x256 map (grid_sample's float32 weights), by one.
An all-black map would divide by zero in step 4; here its HDR map is all zero, with a warning.
"""

import math
import warnings
from functools import lru_cache

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image
from torch import Tensor

from gaffer_envmap.errors import ShapeError

_A = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
_CLAMP = 1.0 - 1e-7
THETA_OFFSET = 1e-6
"""The authors subtract this from arccos(d_z) before the lookup (their inference script): it moves
the sampling row by about 3e-7 px, enough to flip ~0.2-0.8% of a textured map's LDR values by one
LSB."""


@lru_cache(maxsize=8)
def _local_dirs(height: int, width: int) -> Tensor:
    """`[H*W, 3]` float64 d_local of the authors' output grid (step 1)."""
    theta = math.pi / 2 - (torch.arange(height, dtype=torch.float64) + 0.5) * math.pi / height
    phi = math.pi - (torch.arange(width, dtype=torch.float64) + 0.5) * 2 * math.pi / width
    th, ph = torch.meshgrid(theta, phi, indexing="ij")
    return torch.stack(
        [torch.cos(ph) * torch.cos(th), torch.sin(ph) * torch.cos(th), torch.sin(th)], -1
    ).reshape(-1, 3)


def spin_matrices_neural_gaffer(
    spin_deg: "float | int | Tensor", count: int, device: torch.device
) -> Tensor:
    """`[count, 3, 3]` right factors Rz(-D) for `spin_deg` D (scalar or `[count]`): frame k = D N / 360.

    Rz(a) = [[cos a, -sin a, 0], [sin a, cos a, 0], [0, 0, 1]], the matrix the authors build for turntable
    frame k of N with a = -2 pi k / N = -D in radians, so `encode --compat neural-gaffer --spin D` is their
    frame k for any N.

    Raises:
        ShapeError: when `spin_deg` is neither a scalar nor one angle per pose.
    """
    ang = torch.as_tensor(spin_deg, dtype=torch.float64, device=device).reshape(-1)
    if ang.numel() == 1:
        ang = ang.expand(count)
    if ang.numel() != count:
        raise ShapeError("spin_deg", tuple(ang.shape), f"a scalar or [{count}] (one per pose)")
    a = -torch.deg2rad(ang)
    c, s, z, o = torch.cos(a), torch.sin(a), torch.zeros_like(a), torch.ones_like(a)
    return torch.stack([c, -s, z, s, c, z, z, z, o], dim=-1).reshape(count, 3, 3)


def rotate_neural_gaffer(radiance: Tensor, rotations: Tensor, spin: Tensor | None = None) -> Tensor:
    """Steps 1-3 for `[B, He, We, 3]` maps and `[B, 3, 3]` rotations (optional `[B, 3, 3]` right factors).

    Returns `[B, He, We, 3]` float32 rotated maps at source resolution.
    """
    b, he, we, _ = radiance.shape
    m = _A[None].to(rotations.device) @ rotations.to(torch.float64)
    if spin is not None:
        m = m @ spin.to(m)
    d = _local_dirs(he, we).to(rotations.device)[None] @ m  # [B, N, 3]
    # the clamp guards a NaN the authors could hit at |d_z| = 1 + eps; the offset is theirs
    theta = torch.arccos(d[..., 2].clamp(-1.0, 1.0)) - THETA_OFFSET
    phi = torch.atan2(d[..., 1], d[..., 0])
    grid = torch.stack([-phi / math.pi, 2 * theta / math.pi - 1], -1).clamp(-_CLAMP, _CLAMP)
    grid = grid.reshape(b, he, we, 2).to(torch.float32)
    img = radiance.permute(0, 3, 1, 2).to(torch.float32)
    out = F.grid_sample(img, grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    return out.permute(0, 2, 3, 1)


def encode_neural_gaffer(rotated: Tensor, size: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Steps 4-5: uint8 `[B, size, size, 3]` LDR and HDR maps from rotated `[B, He, We, 3]` radiance."""
    # contiguous first: `rotate_neural_gaffer` returns a channels-last view of grid_sample's output,
    # and every elementwise pass below ran twice as slow on its strides (7.3 -> 3.6 ms per
    # 512x256 map); elementwise ops and a max give the same values in any layout
    e = rotated.to(torch.float32).contiguous()
    ldr = torch.clip(e, 0, 1) ** (1 / 2.2)
    # Clamp as the default mode does (encode.HDR_MAX): 10 E overflows float32 above 3.4e37 and the
    # authors' division would give NaN there; below it (every real map) this changes no value.
    log = torch.log1p(10 * e.clamp(max=3.4e38 / 40))
    peak = log.amax(dim=(1, 2, 3), keepdim=True)
    if bool((peak <= 0).any()):
        warnings.warn(
            "an all-black (or non-positive) environment map: the authors' HDR normaliser would divide by "
            "zero; its HDR map is set to 0.",
            stacklevel=3,
        )
    hdr = torch.where(
        peak > 0, log / torch.where(peak > 0, peak, torch.ones_like(peak)), torch.zeros_like(log)
    ).clip(0, 1)
    ldr_u8 = torch.floor(ldr * 255).to(torch.uint8).cpu().numpy()
    hdr_u8 = torch.floor(hdr * 255).to(torch.uint8).cpu().numpy()
    return _pil_resize(ldr_u8, size), _pil_resize(hdr_u8, size)


def _pil_resize(batch_u8: np.ndarray, size: int) -> np.ndarray:
    return np.stack(
        [
            np.asarray(Image.fromarray(img).resize((size, size), Image.Resampling.BILINEAR))
            for img in batch_u8
        ]
    )
