"""Radiance hints: cheap physically based renders of the input's shape under the target lighting.

A 3M-parameter model trained on a CPU cannot learn shape and light transport implicitly from a few
hundred objects (gaffer-tiny model card). DiLightNet (Zeng et al., SIGGRAPH 2024) conditions its
diffusion model on "radiance hints", renders of an estimated geometry with a few reference materials
under the target light; `ModelConfig.hints` does the same with what every path already has, the input
image, its mask and the camera-frame lighting maps E_L / E_H (paper §3.2):

1. Radiance of the target light in the camera frame, recovered exactly from the pair (E_L, E_H)
   (`radiance_from_maps`): E_L = E^(1/2.2) where E < 1 fixes the HDR normaliser of E_H.
2. Normals from the silhouette (`silhouette_normals`): the mask's distance transform inflated into
   a dome (a disc becomes a hemisphere), camera frame (x right, y up, z toward the camera). No
   learning, no weights, defined for any photo with a mask.
3. Under the target light with those normals: a white Lambertian surface (irradiance / pi) and two
   normalised Phong lobes about the mirror direction (exponents 8 and 64: rough and glossy
   reflections), all in linear radiance, then tone-mapped x / (1 + x) and gamma 1/2.2 to [0, 1].

The model sees `[diffuse, glossy_rough, glossy_sharp, normals]` (12 channels, `HINT_CHANNELS`) beside
`[z_t, E(x), E(E_H), E(E_L)]`; outside the mask every hint is 0. Mirroring the image and the maps in
camera x mirrors the hints (tested), so the mirror mean and mirror augmentation stay exact.

With `ModelConfig.hint_geometry == "estimated"` (gaffer-tiny 0.5) the normals come from the
learned estimator (`gaffer_diffusion.geometry.estimator`) instead of the dome, and three more channels
follow (`ESTIMATED_HINT_CHANNELS`): the **de-lit ratio** `log(E_target(n) / pi) - log(L_input(n))`, where
`L_input` is an order-2 spherical-harmonic fit of the input's own linear radiance over its normals
(Ramamoorthi & Hanrahan 2001: nine coefficients hold diffuse lighting): the input's lighting x albedo.
For a diffuse object the true change of shading is this ratio plus log(albedo), so the model is told
which facets brighten and which darken under the target, relative to how the input was lit.
"""

import math
from functools import lru_cache
from typing import Literal

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.images import srgb_to_linear

__all__ = [
    "ESTIMATED_HINT_CHANNELS",
    "HINT_CHANNELS",
    "PHONG_EXPONENTS",
    "HintGeometry",
    "delit_ratio",
    "diffuse_radiance",
    "hints_at",
    "input_radiance_fit",
    "prefiltered_maps",
    "radiance_from_maps",
    "relighting_hints",
    "silhouette_normals",
]

PHONG_EXPONENTS: tuple[int, ...] = (8, 64)
"""Phong exponents of the two specular hints (lobe half-widths about 24 and 8 degrees); powers of 2."""

HINT_CHANNELS = 3 * (1 + len(PHONG_EXPONENTS)) + 3
"""Diffuse (3) + one RGB hint per Phong lobe (3 each) + normals (3)."""

ESTIMATED_HINT_CHANNELS = HINT_CHANNELS + 3
"""The same with estimated normals, plus the de-lit ratio (3): `hint_geometry == "estimated"`."""

HintGeometry = Literal["silhouette", "estimated"]
"""Where the hints' normals come from: the silhouette dome (no weights) or the learned estimator."""

_RATIO_EPS = 0.01  # linear radiance added before the logs of the de-lit ratio
_RATIO_RANGE = 4.0  # the ratio's log is divided by this and clipped to [-1, 1]

LOBE_GRID = 24
"""Side of the direction grid the camera-frame map is pooled to for the lobe integrals (576 dirs)."""

PREFILTER_GRID = 48
"""Side of the square camera-frame grid the lobe-filtered maps are sampled on (3.75 x 7.5 degrees)."""

_LDR_GAMMA = 2.2
_HDR_GAIN = 10.0  # gaffer_envmap.encode: E_H = log1p(10 E) / log1p(10 peak)


def radiance_from_maps(
    ldr: Float[Tensor, "B 3 H W"], hdr: Float[Tensor, "B 3 H W"]
) -> Float[Tensor, "B 3 H W"]:
    """Linear camera-frame radiance from gaffer-envmap's E_L and E_H (default encoding).

    E_L = clip(E, 0, 1)^(1/2.2) gives E exactly where it is below 1; there E_H = log1p(10 E) / D fixes
    the map's normaliser D = log1p(10 peak), and then E = expm1(D E_H) / 10 everywhere. D is the median
    over pixels with E_L in (0.05, 0.95); a map with no such pixel (all black or all above 1) falls back
    to its darkest pixel being 1.

    Returns:
        `[B, 3, H, W]` non-negative float32 radiance.
    """
    ldr = ldr.float().clamp(0, 1)
    hdr = hdr.float().clamp(0, 1)
    b = ldr.shape[0]
    e_low = ldr.pow(_LDR_GAMMA)
    ok = (ldr > 0.05) & (ldr < 0.95) & (hdr > 1e-4)
    ratio = torch.log1p(_HDR_GAIN * e_low) / hdr.clamp_min(1e-4)
    denom = torch.empty(b, device=ldr.device)
    for i in range(b):
        r = ratio[i][ok[i]]
        if r.numel() > 0:
            denom[i] = r.median()
        else:
            lit = hdr[i][hdr[i] > 0]
            denom[i] = math.log1p(_HDR_GAIN) / float(lit.min()) if lit.numel() else 0.0
    return torch.expm1(hdr * denom.view(b, 1, 1, 1)).div_(_HDR_GAIN).clamp_min_(0.0)


def _erode_steps(mask: Float[Tensor, "B 1 H W"], steps: int) -> Float[Tensor, "B 1 H W"]:
    """Distance to the background in pixels (octagonal metric: alternating 3x3 square / cross
    erosions, within ~8% of Euclidean), capped at `steps`."""
    inside = (mask > 0.5).float()
    dist = torch.zeros_like(inside)
    cur = inside
    cross = torch.tensor([[0.0, 1.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.0]], device=mask.device)
    for k in range(steps):
        if not bool(cur.any()):
            break
        dist = dist + cur
        if k % 2 == 0:
            cur = -F.max_pool2d(-F.pad(cur, (1, 1, 1, 1), value=0.0), 3, stride=1)
        else:
            hit = F.conv2d(F.pad(cur, (1, 1, 1, 1), value=0.0), cross.view(1, 1, 3, 3))
            cur = (hit > 4.5).float()
    return dist


def _blur(x: Tensor, sigma: float) -> Tensor:
    radius = max(math.ceil(2.5 * sigma), 1)
    t = torch.arange(-radius, radius + 1, device=x.device, dtype=x.dtype)
    k = torch.exp(-0.5 * (t / sigma) ** 2)
    k = k / k.sum()
    c = x.shape[1]
    x = F.conv2d(
        F.pad(x, (radius, radius, 0, 0), mode="replicate"),
        k.view(1, 1, 1, -1).repeat(c, 1, 1, 1),
        groups=c,
    )
    return F.conv2d(
        F.pad(x, (0, 0, radius, radius), mode="replicate"),
        k.view(1, 1, -1, 1).repeat(c, 1, 1, 1),
        groups=c,
    )


def silhouette_normals(mask: Float[Tensor, "B 1 H W"]) -> Float[Tensor, "B 3 H W"]:
    """Camera-frame unit normals of the mask inflated into a dome (x right, y up, z to the camera).

    Height h = sqrt(2 R d - d^2) for the distance d to the silhouette and R its maximum (a disc gives
    a hemisphere), blurred by ~1.5% of the side, differentiated. Background pixels get (0, 0, 1).
    """
    h, w = mask.shape[2:]
    d = _erode_steps(mask, max(h, w) // 2 + 1)
    r = d.amax(dim=(2, 3), keepdim=True).clamp_min(1.0)
    height = torch.sqrt((2 * r * d - d * d).clamp_min(0.0))
    height = _blur(height, max(1.0, 0.015 * max(h, w)))
    gx = F.pad(height[..., :, 2:] - height[..., :, :-2], (1, 1, 0, 0), mode="replicate") / 2
    gy = F.pad(height[..., 2:, :] - height[..., :-2, :], (0, 0, 1, 1), mode="replicate") / 2
    # image rows go down, camera y goes up: dh/dy_up = -dh/drow
    n = torch.cat([-gx, gy, torch.ones_like(gx)], dim=1)
    n = n / n.norm(dim=1, keepdim=True)
    inside = mask > 0.5
    flat = torch.tensor([0.0, 0.0, 1.0], device=mask.device).view(1, 3, 1, 1)
    return torch.where(inside, n, flat)


@lru_cache(maxsize=8)
def _lobe_grid(n: int, device: str) -> tuple[Tensor, Tensor]:
    """Directions `[n*n, 3]` and solid angles `[n*n]` of an n x n camera-frame map's pixels
    (gaffer-envmap's "neural-gaffer-camera" layout, `gaffer_envmap.rotate._camera_grid`)."""
    v = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    u = (torch.arange(n, dtype=torch.float64) + 0.5) / n
    theta = (math.pi * v)[:, None].expand(n, n)  # polar angle from camera up (+y)
    phi = (2 * math.pi * (0.5 - u))[None, :].expand(n, n)  # 0 at +x, +pi/2 at forward (-z)
    dirs = torch.stack(
        [theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin()], dim=-1
    ).reshape(-1, 3)
    omega = (theta.sin() * (math.pi / n) * (2 * math.pi / n)).reshape(-1)
    return dirs.float().to(device), omega.float().to(device)


def _pool_radiance(radiance: Float[Tensor, "B 3 H W"], n: int) -> Float[Tensor, "B 3 n n"]:
    """Solid-angle-weighted area pooling of a camera-frame map to n x n (power preserving)."""
    h = radiance.shape[2]
    theta = math.pi * (torch.arange(h, device=radiance.device, dtype=torch.float32) + 0.5) / h
    w = theta.sin().view(1, 1, h, 1)
    num = F.adaptive_avg_pool2d(radiance * w, n)
    den = F.adaptive_avg_pool2d(w.expand(1, 1, h, radiance.shape[3]), n)
    return num / den.clamp_min(1e-8)


def _tone(x: Tensor) -> Tensor:
    return (x / (1.0 + x)).clamp_min(0.0).pow(1.0 / _LDR_GAMMA)


def prefiltered_maps(radiance: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 9 P P"]:
    """The camera-frame map convolved with the hint lobes, sampled on a `PREFILTER_GRID` square grid.

    Channels: irradiance / pi (cosine lobe about the normal), then each normalised Phong lobe (about
    the mirror direction), RGB each. Looking these up per pixel (`_lookup`) replaces a per-pixel
    integral over all directions (what real-time renderers do with prefiltered environment maps).
    """
    src = _pool_radiance(radiance.float(), LOBE_GRID)  # [B, 3, n, n]
    dirs, omega = _lobe_grid(LOBE_GRID, str(radiance.device))  # [K, 3], [K]
    light = src.flatten(2).transpose(1, 2) * omega[None, :, None]  # [B, K, 3] radiance x dOmega
    out_dirs, _ = _lobe_grid(PREFILTER_GRID, str(radiance.device))  # [P*P, 3]
    cos = (out_dirs @ dirs.T).clamp_min(0.0)  # [PP, K]
    kernels = [cos / math.pi]  # white Lambertian: irradiance / pi
    lobe, power = cos, 1
    for s in PHONG_EXPONENTS:  # powers of two: repeated squaring
        while power < s:
            lobe = lobe * lobe
            power *= 2
        kernels.append(lobe / (lobe @ omega).clamp_min(1e-12)[:, None])
    kernel = torch.cat(kernels)  # [L*PP, K]
    b, p = radiance.shape[0], PREFILTER_GRID
    filtered = kernel @ light  # [B, L*PP, 3]
    filtered = filtered.view(b, len(kernels), p, p, 3).permute(0, 1, 4, 2, 3)
    return filtered.reshape(b, 3 * len(kernels), p, p)


def _lookup(maps: Float[Tensor, "B C P P"], dirs: Float[Tensor, "B 3 H W"]) -> Tensor:
    """Bilinear lookup of camera-frame square lat-long maps in directions `dirs` (wrapping in phi)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    theta = torch.acos(y.clamp(-1.0, 1.0))  # from camera up
    phi = torch.atan2(-z, x)  # 0 at +x, +pi/2 at forward (-z)
    u = torch.remainder(0.5 - phi / (2 * math.pi), 1.0)
    v = theta / math.pi
    p = maps.shape[-1]
    padded = torch.cat([maps[..., -1:], maps, maps[..., :1]], dim=-1)  # one wrapped column a side
    gx = ((u * p + 1.0) / (p + 2)) * 2 - 1  # column u p - 1/2 of the map is u p + 1/2 padded
    gy = v * 2 - 1
    grid = torch.stack([gx, gy], dim=-1)  # [B, H, W, 2]
    return F.grid_sample(padded, grid, mode="bilinear", padding_mode="border", align_corners=False)


def _quadratic_basis(n: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 9 H W"]:
    """A basis of the polynomials of degree <= 2 in the normal: the span of order-2 real SH (a
    least-squares fit in it equals a fit in SH, whatever the constants)."""
    x, y, z = n[:, 0], n[:, 1], n[:, 2]
    one = torch.ones_like(x)
    return torch.stack([one, x, y, z, x * y, y * z, x * z, x * x - y * y, 3 * z * z - 1], dim=1)


def input_radiance_fit(
    image: Float[Tensor, "B 3 H W"],
    mask: Float[Tensor, "B 1 H W"],
    normals: Float[Tensor, "B 3 H W"],
) -> Float[Tensor, "B 3 H W"]:
    """`L_input(n)`: the input's linear radiance as an order-2 SH function of its normals, per channel.

    A least-squares fit over the unsaturated object pixels (a small ridge keeps an object that shows
    few normals well posed), floored at 5% of its mean over the mask so logs and ratios of it stay
    finite. For a diffuse object of one albedo it is albedo x the input light's irradiance / pi
    (Ramamoorthi & Hanrahan 2001), what `delit_ratio` divides the target's shading by.

    Args:
        image: the input in display sRGB, [0, 1], on white.
        mask: its alpha.
        normals: camera-frame unit normals.
    """
    b = image.shape[0]
    lin = srgb_to_linear(image.float())  # [B, 3, H, W]
    basis = _quadratic_basis(normals.float())  # [B, 9, H, W]
    inside = mask > 0.5
    weight = (inside & (image.amax(dim=1, keepdim=True) < 0.98)).float().flatten(1)  # [B, P]
    a = basis.flatten(2)  # [B, 9, P]
    ata = torch.einsum("bp,bip,bjp->bij", weight, a, a)  # [B, 9, 9]
    ridge = 1e-3 * weight.sum(dim=1).clamp_min(1.0).view(b, 1, 1)
    ata = ata + ridge * torch.eye(9, device=image.device).expand(b, 9, 9)
    aty = torch.einsum("bp,bip,bcp->bci", weight, a, lin.flatten(2))  # [B, 3, 9]
    coeffs = torch.linalg.solve(ata.unsqueeze(1), aty.unsqueeze(-1)).squeeze(-1)  # [B, 3, 9]
    fit = torch.einsum("bci,bihw->bchw", coeffs, basis)
    insidef = inside.float()
    mean = (fit * insidef).sum(dim=(2, 3), keepdim=True) / insidef.sum(
        dim=(2, 3), keepdim=True
    ).clamp_min(1.0)
    return torch.maximum(fit, 0.05 * mean.clamp_min(1e-4))


def delit_ratio(
    image: Float[Tensor, "B 3 H W"],
    mask: Float[Tensor, "B 1 H W"],
    normals: Float[Tensor, "B 3 H W"],
    diffuse_target: Float[Tensor, "B 3 H W"],
) -> Float[Tensor, "B 3 H W"]:
    """`log(diffuse_target) - log(L_input(n))` / 4, clipped to [-1, 1], zero outside the mask.

    `L_input` is `input_radiance_fit`: the input's lighting x albedo as a function of the normal.

    Args:
        image: the input in display sRGB, [0, 1], on white.
        mask: its alpha.
        normals: camera-frame unit normals.
        diffuse_target: irradiance / pi of the target light at each pixel (linear radiance of a white
            Lambertian surface, `diffuse_radiance`).
    """
    fit = input_radiance_fit(image, mask, normals)
    ratio = torch.log(diffuse_target.float() + _RATIO_EPS) - torch.log(fit + _RATIO_EPS)
    return (ratio / _RATIO_RANGE).clamp(-1.0, 1.0) * (mask > 0.5).float()


def diffuse_radiance(
    normals: Float[Tensor, "B 3 H W"],
    ldr: Float[Tensor, "B 3 S S"],
    hdr: Float[Tensor, "B 3 S S"],
) -> Float[Tensor, "B 3 H W"]:
    """Linear radiance of a white Lambertian surface (irradiance / pi) with camera-frame `normals`
    under the lighting of the camera-frame maps E_L / E_H: the hints' diffuse channel before tone
    mapping. No visibility: a facet is lit by its whole hemisphere, shadows and all."""
    maps = prefiltered_maps(radiance_from_maps(ldr, hdr).to(normals.device))
    return _lookup(maps[:, :3], normals)


def relighting_hints(
    mask: Float[Tensor, "B 1 H W"],
    ldr: Float[Tensor, "B 3 S S"],
    hdr: Float[Tensor, "B 3 S S"],
    *,
    normals: Float[Tensor, "B 3 H W"] | None = None,
    image: Float[Tensor, "B 3 H W"] | None = None,
) -> Float[Tensor, "B C H W"]:
    """The hint channels of `ModelConfig.hints` in [-1, 1] (see the module docstring).

    Args:
        mask: the input's object mask (its alpha) in [0, 1] at the model resolution.
        ldr, hdr: the target lighting's camera-frame maps E_L, E_H (gaffer-envmap default encoding).
        normals: camera-frame normals of the input (`input_normals`); None: the silhouette dome.
        image: the input (display sRGB on white); when given, the 3 de-lit ratio channels follow
            (`delit_ratio`, with `normals`).

    Returns:
        `[B, 12, H, W]` (`[B, 15, H, W]` with `image`): diffuse, Phong 8, Phong 64 (tone-mapped,
        mapped to [-1, 1]), the normals (and the de-lit ratio), all zero outside the mask.
    """
    device = mask.device
    maps = prefiltered_maps(radiance_from_maps(ldr, hdr).to(device))  # [B, 9, P, P]
    if normals is None:
        normals = silhouette_normals(mask)  # [B, 3, H, W]
    # mirror direction of the view vector v = +z (orthographic camera): r = 2 (n.v) n - v
    refl = 2.0 * normals[:, 2:3] * normals - torch.tensor([0.0, 0.0, 1.0], device=device).view(
        1, 3, 1, 1
    )
    diffuse = _lookup(maps[:, :3], normals)
    glossy = _lookup(maps[:, 3:], refl)
    inside = (mask > 0.5).float()
    encoded = (_tone(torch.cat([diffuse, glossy], dim=1)) * 2.0 - 1.0) * inside
    parts = [encoded, normals * inside]
    if image is not None:
        parts.append(delit_ratio(image, mask, normals, diffuse))
    return torch.cat(parts, dim=1)


def hints_at(
    mask: Float[Tensor, "B 1 H W"],
    ldr: Float[Tensor, "B 3 S S"],
    hdr: Float[Tensor, "B 3 S S"],
    size: int,
    *,
    geometry: HintGeometry = "silhouette",
    image: Float[Tensor, "B 3 H W"] | None = None,
    normals: Float[Tensor, "B 3 H W"] | None = None,
) -> Float[Tensor, "B C s s"]:
    """`relighting_hints` at `size` px: area-downsampled for a latent model (the one place both
    training and `encode_conditions` take them from).

    `geometry` "silhouette": 12 channels from the dome (or from `normals`). "estimated": 15
    channels, from `normals` (`gaffer_diffusion.geometry.input_normals`; the benchmark's oracle
    passes true normals) and the de-lit ratio of `image`.
    """
    if geometry == "estimated":
        if image is None or normals is None:
            raise ValueError("estimated hint geometry needs the input images and their normals")
        hints = relighting_hints(mask, ldr, hdr, normals=normals.to(mask.device), image=image)
    else:
        hints = relighting_hints(mask, ldr, hdr, normals=normals)
    if hints.shape[-1] != size:
        hints = F.interpolate(hints, size=(size, size), mode="area")
    return hints
