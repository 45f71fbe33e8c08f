"""The model's two lighting maps (paper section 3.2, "HDR-LDR conditioning"): E_L and E_H, camera frame.

- E_L (LDR) = clip(E, 0, 1) ** (1/2.2): detail in the dim regions (reflections).
- E_H (HDR) = log1p(10 E) / normaliser: the whole range, log-compressed.

Two modes:
- `compat="neural-gaffer"`: the authors' exact pipeline (`compat.py`), uint8-quantised, for the released
  checkpoint.
- `compat="default"`: rotation straight to the `size x size` grid in linear space, power-exact per
  channel to float round-off without a global gain (`filter="conservative"`, `conservative.py`, through
  a fused numba kernel on the CPU; `filter="area"`, the default before "conservative", is within ~1%
  for most maps), seam wrap, exact identity, no quantisation unless asked (then round-to-nearest), and an HDR
  normaliser taken from the SOURCE map (its peak after the same pre-filter), so it does not change as the
  camera turns, and the relative brightness of different maps survives... up to each map's own peak.
  See docs/encodings.md for a side-by-side figure.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from gaffer_envmap.compat import (
    encode_neural_gaffer,
    rotate_neural_gaffer,
    spin_matrices_neural_gaffer,
)
from gaffer_envmap.compat_mode import Compat, CompatArg, compat_problem, is_compat
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import GafferEnvmapError, ShapeError
from gaffer_envmap.poses import W2CBlender
from gaffer_envmap.resample import resize_conservative_torch
from gaffer_envmap.rotate import (
    Filter,
    as_radiance_batch,
    as_rotations,
    rotate_channels_first,
    source_height,
)
from gaffer_envmap.writers import quantize, quantize_float

LDR_GAMMA = 2.2
HDR_GAIN = 10.0
HDR_MAX = float(torch.finfo(torch.float32).max) / (4 * HDR_GAIN)
"""Radiance is clamped here before `log1p(10 E)`: 10 E would overflow float32 to inf (and inf * 0 = NaN
in the normalisation) for E > 3.4e37. No physical map comes near it (half-float EXR tops out at 65504)."""


@dataclass(frozen=True)
class LightingEncoding:
    """The model's lighting conditioning, channels-first, values in [0, 1].

    Attributes:
        ldr: `[B, 3, S, S]` E_L, camera frame.
        hdr: `[B, 3, S, S]` E_H, camera frame.
        compat: which pipeline made them.
    """

    ldr: Tensor
    hdr: Tensor
    compat: Compat = "default"

    def to_uint8(self) -> tuple[np.ndarray, np.ndarray]:
        """`[B, S, S, 3]` uint8 pair (round-to-nearest; exact for compat maps, which are already 8-bit)."""

        def q(t: Tensor) -> np.ndarray:
            return quantize(t.permute(0, 2, 3, 1))

        return q(self.ldr), q(self.hdr)


def ldr_encode(radiance_linear: Tensor) -> Tensor:
    """E_L = clip(E, 0, 1) ** (1/2.2), elementwise; NaN -> 0."""
    return torch.nan_to_num(radiance_linear.clamp(0, 1), nan=0.0) ** (1 / LDR_GAMMA)


def hdr_encode(radiance_linear: Tensor, peak: Tensor) -> Tensor:
    """E_H = log1p(10 E) / log1p(10 peak), clipped to [0, 1]; an all-black map (peak 0) gives zeros.

    `peak` broadcasts against `radiance_linear` (e.g. `[B, 1, 1, 1]`).
    """
    e = torch.nan_to_num(radiance_linear.clamp(0, HDR_MAX), nan=0.0)
    denom = torch.log1p(HDR_GAIN * peak.clamp(0, HDR_MAX))
    safe = torch.where(denom > 0, denom, torch.ones_like(denom))
    return torch.where(denom > 0, torch.log1p(HDR_GAIN * e) / safe, torch.zeros_like(e)).clamp(0, 1)


def _encode_finite(rotated: Tensor, peak: Tensor) -> tuple[Tensor, Tensor]:
    """`ldr_encode` and `hdr_encode` for finite input, in place where possible (the hot path).

    exp(log(x) / 2.2) is the same power as x ** (1 / 2.2) (log 0 = -inf maps back to 0), about twice as
    fast on CPU.
    """
    ldr = rotated.clamp(0, 1).log_().mul_(1 / LDR_GAMMA).exp_()
    denom = torch.log1p(HDR_GAIN * peak.clamp(0, HDR_MAX))
    inv = torch.where(denom > 0, 1 / torch.where(denom > 0, denom, torch.ones_like(denom)), 0.0)
    hdr = rotated.clamp(0, HDR_MAX).mul_(HDR_GAIN).log1p_().mul_(inv).clamp_(0, 1)
    return ldr, hdr


def _pair(
    env: "EnvironmentMap | Sequence[EnvironmentMap] | np.ndarray | Tensor",
    w2c: "W2CBlender | Sequence[W2CBlender] | np.ndarray | Tensor",
    device: "torch.device | str | None",
) -> tuple[Tensor, Tensor]:
    src = as_radiance_batch(env, device)
    rot = as_rotations(w2c, src.device)
    if src.shape[0] == 1 and rot.shape[0] > 1:
        src = src.expand(rot.shape[0], -1, -1, -1)
    elif rot.shape[0] == 1 and src.shape[0] > 1:
        rot = rot.expand(src.shape[0], -1, -1)
    if src.shape[0] != rot.shape[0]:
        raise ShapeError(
            "w2c_blender",
            tuple(rot.shape),
            f"[{src.shape[0]}, 3, 4] (one pose per map, or one for all)",
        )
    return src, rot


def encode_lighting(
    env: "EnvironmentMap | Sequence[EnvironmentMap] | np.ndarray | Tensor",
    w2c_blender: "W2CBlender | Sequence[W2CBlender] | np.ndarray | Tensor",
    *,
    size: int = 256,
    compat: CompatArg = "default",
    spin_deg: "float | int | Tensor" = 0.0,
    filter: Filter = "conservative",
    supersample: int = 2,
    quantize: bool = False,
    device: "torch.device | str | None" = None,
) -> LightingEncoding:
    """E_L and E_H in the camera frame, ready for the VAE (after mapping [0, 1] -> [-1, 1]).

    Args:
        env: world maps (Blender convention) `[B, He, 2He, 3]`, or one map for all poses.
        w2c_blender: Blender world-to-camera poses `[B, 3, 4]`, or one pose for all maps.
        size: output side S (the paper: 256).
        compat: "default" (correct) or "neural-gaffer" (bit-compatible with the released checkpoint).
        spin_deg: extra turn of the light about world up, degrees, scalar or `[B]`. Default mode:
            counter-clockwise seen from above. `compat="neural-gaffer"`: the authors' turntable sense,
            D is their frame k = D N / 360 (Rz(-D) on the right of the direction rotation), which
            turns the light clockwise.
        filter, supersample: rotation filter of the default mode (see `rotate_to_camera`).
        quantize: default mode only: round to 8 bit (round-to-nearest), as a PNG round trip would.
        device: torch device for the computation.

    Returns:
        `LightingEncoding` with `ldr` and `hdr` `[B, 3, S, S]` float32 in [0, 1].

    Example:
        >>> import numpy as np
        >>> from gaffer_envmap.poses import orbit_w2c_blender
        >>> env = np.full((16, 32, 3), 0.5, np.float32)
        >>> enc = encode_lighting(env, orbit_w2c_blender(0.0, 0.0), size=8)
        >>> tuple(enc.ldr.shape), round(float(enc.ldr.mean()), 4)
        ((1, 3, 8, 8), 0.7297)
    """
    src, rot = _pair(env, w2c_blender, device)
    if size < 1:
        raise GafferEnvmapError(f"`size` must be >= 1, got {size}.")
    if not is_compat(compat):
        raise GafferEnvmapError(compat_problem("compat", compat))
    if compat == "neural-gaffer":
        spin = None
        if not (isinstance(spin_deg, float | int) and spin_deg == 0):
            # the authors' sense (docs/encodings.md): D is their turntable frame k = D N / 360,
            # Rz(-D) on the right
            spin = spin_matrices_neural_gaffer(spin_deg, src.shape[0], src.device)
        # One map at a time: the same values as one batched call (tested), and faster per map on the
        # CPU, where the batch's float64 direction tensors no longer fit in cache (32 maps
        # at once did 0.75x the one-at-a-time rate in benchmarks/bench_envmap_preprocess.py).
        parts = [
            encode_neural_gaffer(
                rotate_neural_gaffer(
                    src[i : i + 1], rot[i : i + 1], None if spin is None else spin[i : i + 1]
                ),
                size,
            )
            for i in range(src.shape[0])
        ]
        ldr_u8 = np.concatenate([p[0] for p in parts])
        hdr_u8 = np.concatenate([p[1] for p in parts])
        to_t = lambda a: torch.from_numpy(a).to(src.device).permute(0, 3, 1, 2).float() / 255  # noqa: E731
        return LightingEncoding(ldr=to_t(ldr_u8), hdr=to_t(hdr_u8), compat=compat)
    if filter == "conservative" and src.device.type == "cpu" and src.dtype == torch.float32:
        # The fused numba kernel (`_fast_cpu`); `conservative.rotate_conservative` is its twin.
        # No torch op on the way in: torch's OpenMP workers spin for a while after a parallel op and
        # took the cores from numba's (a 2-thread `isfinite` here made the kernel 12 ms instead of
        # 9 ms per map), so the finite check is numpy's.
        from gaffer_envmap._fast_cpu import encode_conservative_cpu
        from gaffer_envmap.rotate import _spin_matrix

        arr = src.contiguous().numpy()
        if not np.isfinite(arr).all():  # NaN/Inf pixels would smear through the filters
            arr = np.nan_to_num(arr, nan=0.0, posinf=0.0, neginf=0.0)
        m = rot.to(torch.float64) @ _spin_matrix(spin_deg, rot.shape[0], rot.device).transpose(1, 2)
        ldr_np, hdr_np = encode_conservative_cpu(
            arr, m.numpy(), size, supersample, torch.get_num_threads()
        )
        ldr, hdr = torch.from_numpy(ldr_np), torch.from_numpy(hdr_np)
        if quantize:
            ldr, hdr = quantize_float(ldr), quantize_float(hdr)
        return LightingEncoding(ldr=ldr, hdr=hdr, compat=compat)
    if not bool(torch.isfinite(src).all()):  # NaN/Inf pixels would smear through the filters
        src = torch.nan_to_num(src, nan=0.0, posinf=0.0, neginf=0.0)
    src = resize_conservative_torch(
        src, source_height(filter, src.shape[1], size, size, supersample)
    )
    rotated = rotate_channels_first(
        src,
        rot,
        size,
        size,
        filter=filter,
        supersample=supersample,
        spin_deg=spin_deg,
        pairing="zip",
    )  # [B, 3, S, S]
    # Rotation-invariant normaliser: the source's peak at the resolution the rotation reads.
    peak = src.amax(dim=(1, 2, 3)).reshape(-1, 1, 1, 1)
    ldr, hdr = _encode_finite(rotated, peak)
    if quantize:
        ldr, hdr = quantize_float(ldr), quantize_float(hdr)
    return LightingEncoding(ldr=ldr, hdr=hdr, compat=compat)
