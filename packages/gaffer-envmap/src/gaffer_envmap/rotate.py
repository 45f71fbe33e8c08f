"""Rotate world environment maps into camera frames (Neural Gaffer, section 3.2), batched in torch.

The model sees lighting in the camera's frame: each pixel of the rotated map is a fixed direction relative
to the camera (layout "neural-gaffer-camera": centre column = camera right, u = 0.25 = viewing direction,
u = 0.75 = towards the viewer, top row = camera up). We pull: for every output pixel we take its camera-frame
direction, rotate it into the world, and look the world map up there.

Unlike the authors' pipeline (reference section 4; reproduced in `compat.py`), this one
- writes straight to the requested output grid (no full-resolution intermediate, no resize afterwards);
- wraps the u = 0/1 seam and crosses the poles correctly (the row above row 0 is row 0 turned by half);
- is exact where it should be: an identity pose, or a yaw by whole pixels (same size in and out), is
  detected and done as a permutation, so it returns the input bit for bit / equals `np.roll`;
- conserves power by default: "conservative" (`conservative.py`) reads bilinear sub-samples of the
  source, each texel scaled by its own gain Omega_i / C_i so that the total read of every texel equals
  its solid angle: power is exact per channel and per map, to float round-off, with no global gain
  (the price is a local ripple of the gain on flat maps, about 0.5% rms, 6% at worst);
- "area" averages s x s stratified bilinear sub-samples per output pixel, weighted by their solid angle,
  after a conservative (power-exact) pre-downsample of the source to about s samples per output pixel
  (measured median power error 1.5% for 0.5-2 degree suns at s = 2, up to 6.4% for a sun the sub-samples
  miss); `renormalize=True` then rescales each map so total power matches the source exactly (at the
  price of a global gain that can shift dim regions when a sun is under-sampled, hence off by default).
  gaffer-tiny was trained on it, so gaffer-diffusion asks for it by name. "bilinear" point-samples once
  per pixel (right when magnifying).

Shapes: maps are channels-last `[M, He, We, 3]`, poses `[P, 3, 3]` world -> Blender camera rotations.
"""

import math
from collections.abc import Sequence
from functools import lru_cache
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

from gaffer_envmap.conservative import conservative_height, rotate_conservative
from gaffer_envmap.conventions import row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import GafferEnvmapError, PoseError, ShapeError
from gaffer_envmap.poses import W2CBlender, check_rotation
from gaffer_envmap.resample import resize_conservative_torch

Filter = Literal["conservative", "area", "bilinear"]
Pairing = Literal["outer", "zip"]


def as_radiance_batch(
    envmap: "EnvironmentMap | np.ndarray | Tensor | Sequence[EnvironmentMap]",
    device: "torch.device | str | None" = None,
) -> Tensor:
    """`[M, He, We, 3]` float32 tensor from one or many maps (Blender convention, centre-aligned)."""
    if isinstance(envmap, EnvironmentMap):
        envmap = [envmap]
    if isinstance(envmap, Sequence) and not isinstance(envmap, Tensor | np.ndarray):
        for e in envmap:
            if e.convention != "blender" or e.alignment != "center":
                raise GafferEnvmapError(
                    f"`envmap` is in convention {e.convention!r} / alignment {e.alignment!r}; convert it with "
                    "`convert_convention(env, 'blender')` (and `to_center_alignment`) first."
                )
        arr = torch.from_numpy(np.stack([e.radiance_linear for e in envmap]))
    elif isinstance(envmap, np.ndarray):
        # EnvironmentMap arrays are read-only; torch wants writable memory (copy only then).
        arr = torch.from_numpy(envmap if envmap.flags.writeable else envmap.copy())
    else:
        arr = torch.as_tensor(envmap)
    if arr.ndim == 3:
        arr = arr[None]
    if arr.ndim != 4 or arr.shape[-1] != 3 or arr.shape[2] != 2 * arr.shape[1]:
        raise ShapeError("envmap", tuple(arr.shape), "[M, He, 2*He, 3] or [He, 2*He, 3]")
    return arr.to(device=device, dtype=torch.float32)


def as_rotations(
    w2c_blender: "W2CBlender | Sequence[W2CBlender] | np.ndarray | Tensor",
    device: "torch.device | str | None" = None,
) -> Tensor:
    """`[P, 3, 3]` float64 world -> Blender-camera rotations from poses or `[P?, 3, 3|4]` / `[P?, 4, 4]` arrays.

    Raises:
        PoseError: for wrong shapes or matrices that are not rotations.
    """
    if isinstance(w2c_blender, W2CBlender):
        w2c_blender = [w2c_blender]
    if isinstance(w2c_blender, Sequence) and not isinstance(w2c_blender, Tensor | np.ndarray):
        mats = np.stack([p.rotation for p in w2c_blender])
    else:
        mats = (
            w2c_blender.detach().cpu().double().numpy()
            if isinstance(w2c_blender, Tensor)
            else np.asarray(w2c_blender, np.float64)
        )
        if mats.ndim == 2:
            mats = mats[None]
        if mats.ndim != 3 or mats.shape[1] not in (3, 4) or mats.shape[2] not in (3, 4):
            raise PoseError(
                f"`w2c_blender` has shape {mats.shape}, expected [P, 3, 4], [P, 3, 3] or [P, 4, 4]."
            )
        mats = mats[:, :3, :3]
        for i, m in enumerate(mats):
            check_rotation(m, f"w2c_blender[{i}]")
    return torch.from_numpy(np.ascontiguousarray(mats)).to(device=device)


@lru_cache(maxsize=32)
def _camera_grid(height: int, width: int, ss: int, device_str: str) -> tuple[Tensor, Tensor]:
    """Camera-frame sub-sample directions `[height*ss, width*ss, 3]` and row weights `[height*ss]` (float32).

    Sub-samples sit at the centres of an ss x ss split of each output pixel; their weight is the solid
    angle of their cell, normalised within the pixel (so a pixel's value is an Omega-weighted mean).
    """
    hs, ws = height * ss, width * ss
    v = (torch.arange(hs, dtype=torch.float64) + 0.5) / hs
    u = (torch.arange(ws, dtype=torch.float64) + 0.5) / ws
    theta = math.pi * v  # polar angle from camera up (+y)
    phi = 2 * math.pi * (0.5 - u)  # 0 at camera right (+x), +pi/2 at the viewing direction (-z)
    st, ct = torch.sin(theta)[:, None], torch.cos(theta)[:, None]
    # neural-gaffer-camera layout: d = cos(t) up + sin(t) (cos(p) right + sin(p) forward), forward = -z.
    dirs = torch.stack(
        [st * torch.cos(phi)[None, :], ct.expand(hs, ws), -st * torch.sin(phi)[None, :]], dim=-1
    )
    w = torch.from_numpy(row_solid_angle(hs, ws)).reshape(height, ss)
    w = (w / w.sum(dim=1, keepdim=True)).reshape(hs)
    return dirs.to(device=device_str, dtype=torch.float32), w.to(
        device=device_str, dtype=torch.float32
    )


def _spin_matrix(spin_deg: "float | int | Tensor", count: int, device: torch.device) -> Tensor:
    """`[count, 3, 3]` rotations about world +z by -spin (the lookup turns opposite to the light)."""
    ang = torch.as_tensor(spin_deg, dtype=torch.float64, device=device).reshape(-1)
    if ang.numel() == 1:
        ang = ang.expand(count)
    if ang.numel() != count:
        raise ShapeError("spin_deg", tuple(ang.shape), f"a scalar or [{count}] (one per pose)")
    a = torch.deg2rad(-ang)
    c, s, z, o = torch.cos(a), torch.sin(a), torch.zeros_like(a), torch.ones_like(a)
    return torch.stack([c, -s, z, s, c, z, z, z, o], dim=-1).reshape(count, 3, 3)


def padded_grid(
    rotations: Tensor,
    height: int,
    width: int,
    src_height: int,
    ss: int = 1,
    spin_deg: "float | int | Tensor" = 0.0,
) -> Tensor:
    """`grid_sample` coordinates `[P, height*ss, width*ss, 2]` into a `_pad_periodic` source of
    `src_height` rows (Blender layout), align_corners=True.

    Source column c = u We - 1/2 and row r = v He - 1/2 (pixel centres at integers) become padded
    coordinates c + 1, r + 1, which stay inside [0.5, We + 0.5] x [0.5, He + 0.5]: the bilinear kernel
    never leaves the padded image, so the seam wraps and the poles cross without any clamping.
    """
    device = rotations.device
    dirs_cam, _ = _camera_grid(height, width, ss, str(device))
    p = rotations.shape[0]
    # d_world = R^T d_cam; as row vectors d_cam @ R. Spin: lookup = Rz(-spin) d_world.
    m = rotations.to(torch.float64) @ _spin_matrix(spin_deg, p, device).transpose(1, 2)
    hs, ws = dirs_cam.shape[:2]
    planes = dirs_cam.reshape(hs * ws, 3).T.contiguous()  # [3, N]: contiguous x, y, z planes
    mf = m.float()
    # World components as contiguous [P, N] planes (faster trig than strided views of a [P, N, 3]).
    x, y, z = ((mf[:, :, k] @ planes).reshape(p, hs, ws) for k in range(3))
    src_width = 2 * src_height
    # u = 1/2 - atan2(y, x) / 2pi, v = acos(z) / pi, folded into grid_sample's [-1, 1] range.
    gx = (
        torch.atan2(y, x)
        .mul_(-src_width / (math.pi * (src_width + 1)))
        .add_(src_width / (src_width + 1) + 1.0 / (src_width + 1) - 1.0)
    )
    gy = (
        torch.acos(z.clamp(-1.0, 1.0))
        .mul_(2 * src_height / (math.pi * (src_height + 1)))
        .add_(1.0 / (src_height + 1) - 1.0)
    )
    return torch.stack([gx, gy], dim=-1)


def _pad_periodic(src_cf: Tensor) -> Tensor:
    """`[M, 3, He+2, We+2]` contiguous: one column wrapped on each side; above row 0 and below the last
    row, the same row turned by half a turn (its neighbour across the pole). One strided copy of the
    source plus the borders (this also turns a channels-last view into contiguous channels-first)."""
    m, c, he, we = src_cf.shape
    out = src_cf.new_empty((m, c, he + 2, we + 2))
    out[:, :, 1:-1, 1:-1] = src_cf
    half = we // 2
    out[:, :, 0, 1 : 1 + we - half] = src_cf[:, :, 0, half:]
    out[:, :, 0, 1 + we - half : -1] = src_cf[:, :, 0, :half]
    out[:, :, -1, 1 : 1 + we - half] = src_cf[:, :, -1, half:]
    out[:, :, -1, 1 + we - half : -1] = src_cf[:, :, -1, :half]
    out[..., 0] = out[..., we]
    out[..., -1] = out[..., 1]
    return out


def _sample(src_cf: Tensor, grid: Tensor, pairing: Pairing) -> Tensor:
    """Bilinear taps of channels-first maps `[M, 3, He, We]` (seam wrapped, poles crossed).

    Returns `[M, P, 3, h, w]` (outer) or `[B, 3, h, w]` (zip).
    """
    m, c, he, we = src_cf.shape
    padded = _pad_periodic(src_cf)
    if pairing == "zip":
        return F.grid_sample(
            padded, grid, mode="bilinear", padding_mode="border", align_corners=True
        )
    p = grid.shape[0]
    stacked = padded.reshape(1, m * c, he + 2, we + 2).expand(p, -1, -1, -1)
    out = F.grid_sample(stacked, grid, mode="bilinear", padding_mode="border", align_corners=True)
    return out.reshape(p, m, c, *grid.shape[1:3]).transpose(0, 1)


def prefilter_height(src_height: int, out_height: int, out_width: int, ss: int) -> int:
    """Source height after the conservative pre-downsample: the smallest divisor-compatible height that
    keeps at least `ss` source pixels per output pixel in both angles (never upsamples)."""
    need = ss * max(out_height, (out_width + 1) // 2)
    h = src_height
    while h % 2 == 0 and h // 2 >= need:
        h //= 2
    return h


def source_height(filter: Filter, src_height: int, out_h: int, out_w: int, ss: int) -> int:
    """Height of the (conservatively pre-downsampled) source that `filter` reads."""
    if filter == "conservative":
        return conservative_height(src_height, out_h, out_w, ss)
    if filter == "area":
        return prefilter_height(src_height, out_h, out_w, ss)
    return src_height


def rotate_to_camera(
    envmap: "EnvironmentMap | Sequence[EnvironmentMap] | np.ndarray | Tensor",
    w2c_blender: "W2CBlender | Sequence[W2CBlender] | np.ndarray | Tensor",
    *,
    height: int | None = None,
    width: int | None = None,
    filter: Filter = "conservative",
    supersample: int = 2,
    renormalize: bool = False,
    spin_deg: "float | int | Tensor" = 0.0,
    pairing: Pairing = "outer",
    device: "torch.device | str | None" = None,
) -> Tensor:
    """Camera-frame maps (layout "neural-gaffer-camera") of world maps seen from camera poses.

    Args:
        envmap: world maps in the Blender convention, `[M, He, 2He, 3]` (or one map).
        w2c_blender: Blender world-to-camera poses, `[P, 3, 4]` (or 3x3 / 4x4, or `W2CBlender`s).
        height: output rows (default: the source's). The model's maps use height = width = 256.
        width: output columns (default 2 * height). Any width works; a 2:1 map has square pixels.
        filter: "conservative" (default; power-exact per channel and per map, see `conservative`;
            its per-cell gain ripples on flat maps by about 0.5% rms, 6% at worst, at supersample 2),
            "area" (solid-angle-weighted box of bilinear sub-samples; power off by up to a few percent
            for sub-pixel suns; the default before "conservative") or "bilinear" (one tap per pixel).
        supersample: s for s x s sub-samples per output pixel (conservative: s rows and as many columns as
            keep them square; area: s x s; >= 1).
        renormalize: rescale each map so output power equals source power exactly (area filter; off by
            default because the gain also moves the sky when a small sun is under-sampled).
        spin_deg: extra turn of the light about world up (counter-clockwise from above), scalar or `[P]`.
        pairing: "outer" -> every map with every pose, `[M, P, H, W, 3]`; "zip" -> map i with pose i,
            `[B, H, W, 3]` (M == P == B).
        device: torch device (default: the map tensor's).

    Returns:
        Linear radiance `[M, P, H, W, 3]` or `[B, H, W, 3]`, float32.

    Raises:
        ShapeError, PoseError, GafferEnvmapError: bad shapes, non-rotations, bad options.

    Example:
        >>> import numpy as np
        >>> from gaffer_envmap.poses import IDENTITY_LAYOUT_W2C
        >>> env = np.random.default_rng(0).random((8, 16, 3)).astype(np.float32)
        >>> out = rotate_to_camera(env, IDENTITY_LAYOUT_W2C, filter="bilinear")
        >>> bool((out[0, 0].numpy() == env).all())
        True
    """
    src = as_radiance_batch(envmap, device)
    rot = as_rotations(w2c_blender, src.device)
    m, he = src.shape[:2]
    p = rot.shape[0]
    if pairing == "zip" and m != p:
        raise ShapeError(
            "w2c_blender", (p, 3, 3), f"[{m}, 3, 3] (pairing='zip' needs one pose per map)"
        )
    if pairing not in ("outer", "zip"):
        raise GafferEnvmapError(f"`pairing` must be 'outer' or 'zip', got {pairing!r}.")
    if filter not in ("conservative", "area", "bilinear"):
        raise GafferEnvmapError(
            f"`filter` must be 'conservative', 'area' or 'bilinear', got {filter!r}."
        )
    if supersample < 1:
        raise GafferEnvmapError(f"`supersample` must be >= 1, got {supersample}.")
    out_h = he if height is None else int(height)
    out_w = 2 * out_h if width is None else int(width)
    if out_h < 1 or out_w < 1:
        raise ShapeError("height/width", (out_h, out_w), "positive sizes")
    out = rotate_channels_first(
        src,
        rot,
        out_h,
        out_w,
        filter=filter,
        supersample=supersample,
        renormalize=renormalize,
        spin_deg=spin_deg,
        pairing=pairing,
    )
    return out.movedim(-3, -1)


def rotate_channels_first(
    src: Tensor,
    rot: Tensor,
    out_h: int,
    out_w: int,
    *,
    filter: Filter = "conservative",
    supersample: int = 2,
    renormalize: bool = False,
    spin_deg: "float | int | Tensor" = 0.0,
    pairing: Pairing = "outer",
) -> Tensor:
    """The work of `rotate_to_camera` on validated tensors: `src` `[M, He, We, 3]`, `rot` `[P, 3, 3]`.

    Returns channels-first `[M, P, 3, h, w]` (outer) or `[B, 3, h, w]` (zip), the layout networks use.
    """
    if filter == "conservative":
        return _rotate_conservative_pairs(src, rot, out_h, out_w, supersample, spin_deg, pairing)
    ss = supersample if filter == "area" else 1
    he = src.shape[1]
    if filter == "area":
        src = resize_conservative_torch(src, prefilter_height(he, out_h, out_w, ss))
    grid = padded_grid(rot, out_h, out_w, src.shape[1], ss, spin_deg)
    src_cf = src.permute(0, 3, 1, 2)
    out = _sample(src_cf, grid, pairing)  # [M, P, 3, h*ss, w*ss] or [B, 3, h*ss, w*ss]
    if ss > 1:
        _, w = _camera_grid(out_h, out_w, ss, str(src.device))
        lead = out.shape[:-2]
        # Solid-angle-weighted mean over the ss x ss sub-samples of each pixel: average the ss columns,
        # weight each sub-row by its share of the pixel's solid angle, sum the ss sub-rows.
        cols = F.avg_pool2d(out.reshape(-1, 1, out_h * ss, out_w * ss), (1, ss))
        out = (cols * w[:, None]).reshape(*lead, out_h, ss, out_w).sum(dim=-2)
    out = _exact_permutations(out, src_cf, rot, spin_deg, pairing)
    if filter == "area" and renormalize:
        out = _renormalize(out, src_cf, pairing)
    return out


def _exact_permutations(
    out: Tensor, src: Tensor, rot: Tensor, spin_deg: "float | int | Tensor", pairing: Pairing
) -> Tensor:
    """Replace the output of every pose that maps the output grid exactly onto the source grid.

    That happens when sizes match and the lookup rotation is the identity layout turned about world up by
    a whole number of pixels (identity, whole-pixel yaws, full turns). The result is then a pure column
    roll of the source: bit-exact whatever the filter (sub-samples would otherwise blur it by a quarter
    pixel).
    """
    he, we = src.shape[2:4]
    if out.shape[-2:] != (he, we):
        return out
    m = rot.to(torch.float64) @ _spin_matrix(spin_deg, rot.shape[0], rot.device).transpose(1, 2)
    # m = R0 Rz(a) for some a  <=>  R0^T m is a rotation about z.
    r0 = torch.as_tensor(_IDENTITY_LAYOUT, dtype=torch.float64, device=rot.device)
    rz = r0.T @ m
    is_yaw = (rz[:, 2, 2] - 1).abs() < 1e-12
    shift = torch.atan2(rz[:, 1, 0], rz[:, 0, 0]) * we / (2 * math.pi)  # lookup turns by -a
    whole = is_yaw & ((shift - shift.round()).abs() < 1e-6)
    if not bool(whole.any()):
        return out
    out = out.clone()
    for p in torch.nonzero(whole).flatten().tolist():
        k = round(float(shift[p]))
        if pairing == "outer":
            out[:, p] = torch.roll(src, -k, dims=3)
        else:
            out[p] = torch.roll(src[p], -k, dims=2)
    return out


def _rotate_conservative_pairs(
    src: Tensor,
    rot: Tensor,
    out_h: int,
    out_w: int,
    ss: int,
    spin_deg: "float | int | Tensor",
    pairing: Pairing,
) -> Tensor:
    """`filter="conservative"` for both pairings (outer pairs every map with every pose first)."""
    src = resize_conservative_torch(src, conservative_height(src.shape[1], out_h, out_w, ss))
    m = rot.to(torch.float64) @ _spin_matrix(spin_deg, rot.shape[0], rot.device).transpose(1, 2)
    n_maps, n_rot = src.shape[0], m.shape[0]
    if pairing == "outer":
        pairs = src[:, None].expand(-1, n_rot, -1, -1, -1).reshape(-1, *src.shape[1:])
        out, _ = rotate_conservative(pairs, m.repeat(n_maps, 1, 1), out_h, out_w, ss)
        out = out.reshape(n_maps, n_rot, *out.shape[1:])
    else:
        out, _ = rotate_conservative(src, m, out_h, out_w, ss)
    return _exact_permutations(out, src.permute(0, 3, 1, 2), rot, spin_deg, pairing)


_IDENTITY_LAYOUT = ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0))


def _renormalize(out: Tensor, src: Tensor, pairing: Pairing) -> Tensor:
    """Scale each rotated map (channels-first) so its power per channel equals the source's."""
    dev = src.device
    om_src = torch.from_numpy(row_solid_angle(src.shape[2], src.shape[3])).to(dev, torch.float64)
    om_out = torch.from_numpy(row_solid_angle(out.shape[-2], out.shape[-1])).to(dev, torch.float64)
    p_src = (src.double() * om_src[:, None]).sum(dim=(-2, -1))  # [M, 3]
    p_out = (out.double() * om_out[:, None]).sum(dim=(-2, -1))  # [M, P, 3] or [B, 3]
    if pairing == "outer":
        p_src = p_src[:, None]
    finite = torch.isfinite(p_src) & torch.isfinite(p_out) & (p_out > 0)
    safe = torch.where(finite, p_out, torch.ones_like(p_out))
    scale = torch.where(finite, p_src / safe, torch.ones_like(p_out))
    return (out.double() * scale[..., None, None]).float()
