"""Real spherical harmonics of environment maps: projection (order <= 4), reconstruction, diffuse irradiance.

Basis: orthonormal real SH without the Condon-Shortley phase, indexed l^2 + l + m, so band 1 is
sqrt(3 / 4pi) * (y, z, x) in the map's own world frame (the ordering graphics code expects).
Irradiance uses the clamped-cosine kernel's SH coefficients (Ramamoorthi & Hanrahan 2001): nine
coefficients (order 2) capture diffuse lighting to about 1% on average; band 3 is exactly zero.
Extreme suns ring in a truncated expansion (negative irradiance behind the sun); `window=True` applies a
Hanning-style window to the bands to tame it (as skylibs does).
"""

import math

import numpy as np

from gaffer_envmap.conventions import direction_grid, get_convention, row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import GafferEnvmapError

MAX_ORDER = 4


def num_coefficients(order: int) -> int:
    """(order + 1)^2."""
    return (order + 1) ** 2


def _check_order(order: int) -> None:
    if not 0 <= order <= MAX_ORDER:
        raise GafferEnvmapError(f"`order` must be in 0..{MAX_ORDER}, got {order}.")


def sh_basis(dirs: np.ndarray, order: int) -> np.ndarray:
    """Real SH `[..., (order+1)^2]` at unit directions `[..., 3]`."""
    _check_order(order)
    d = np.asarray(dirs, dtype=np.float64)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    ct = np.clip(z, -1.0, 1.0)
    st = np.sqrt(np.clip(1.0 - ct * ct, 0.0, None))
    phi = np.arctan2(y, x)
    # Associated Legendre P_l^m(cos theta), no Condon-Shortley phase, by the standard recurrences.
    p: dict[tuple[int, int], np.ndarray] = {(0, 0): np.ones_like(ct)}
    for m in range(1, order + 1):
        p[(m, m)] = (2 * m - 1) * st * p[(m - 1, m - 1)]
    for m in range(order):
        p[(m + 1, m)] = (2 * m + 1) * ct * p[(m, m)]
    for m in range(order + 1):
        for l in range(m + 2, order + 1):
            p[(l, m)] = ((2 * l - 1) * ct * p[(l - 1, m)] - (l + m - 1) * p[(l - 2, m)]) / (l - m)
    out = np.empty((*ct.shape, num_coefficients(order)))
    for l in range(order + 1):
        for m in range(-l, l + 1):
            am = abs(m)
            k = math.sqrt(
                (2 * l + 1) / (4 * math.pi) * math.factorial(l - am) / math.factorial(l + am)
            )
            if m == 0:
                val = k * p[(l, 0)]
            elif m > 0:
                val = math.sqrt(2) * k * np.cos(m * phi) * p[(l, m)]
            else:
                val = math.sqrt(2) * k * np.sin(am * phi) * p[(l, am)]
            out[..., l * l + l + m] = val
    return out


def project_sh(env: EnvironmentMap, order: int = 2) -> np.ndarray:
    """SH coefficients `[(order+1)^2, 3]` of the radiance: c = sum L(w) Y(w) Omega, in the map's frame."""
    _check_order(order)
    dirs = direction_grid(env.height, env.width, env.convention, env.alignment)
    omega = row_solid_angle(env.height, env.width, env.alignment)
    basis = sh_basis(dirs, order)  # [He, We, K]
    radiance = np.nan_to_num(env.radiance_linear.astype(np.float64))
    return np.einsum("hwk,hwc,h->kc", basis, radiance, omega)


def reconstruct_sh(coeffs: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Radiance `[..., 3]` of an SH expansion `[K, 3]` at directions `[..., 3]`."""
    order = round(math.sqrt(coeffs.shape[0])) - 1
    return sh_basis(dirs, order) @ coeffs


def cosine_lobe_coefficients(order: int) -> np.ndarray:
    """A_l, l = 0..order: SH coefficients of max(0, cos) scaled for irradiance (A_0 = pi, A_1 = 2pi/3, ...)."""
    a = np.zeros(order + 1)
    for l in range(order + 1):
        if l == 1:
            a[l] = 2 * math.pi / 3
        elif l % 2 == 0:
            a[l] = (
                2
                * math.pi
                * (-1) ** (l // 2 - 1)
                / ((l + 2) * (l - 1))
                * math.factorial(l)
                / (2**l * math.factorial(l // 2) ** 2)
            )
    return a


def irradiance(
    env: EnvironmentMap, normals: np.ndarray, order: int = 2, window: bool = False
) -> np.ndarray:
    """Diffuse irradiance `[..., 3]`, integral L(w) max(0, n.w) dw, at unit normals `[..., 3]` (map's frame)."""
    coeffs = project_sh(env, order)
    a = cosine_lobe_coefficients(order)
    if window:
        a = a * np.array(
            [0.5 * (1 + math.cos(math.pi * l / (order + 1))) for l in range(order + 1)]
        )
    per_coeff = np.concatenate([np.full(2 * l + 1, a[l]) for l in range(order + 1)])
    return sh_basis(normals, order) @ (coeffs * per_coeff[:, None])


def directionality(env: EnvironmentMap, *, about_up: bool = False) -> float:
    """How strongly the map's diffuse lighting depends on the normal: 0 for a uniform sky, 2 for one sun.

    The ratio of the band-1 to the band-0 term of the luminance irradiance, A_1 |L_1| Y_1 / (A_0 L_0
    Y_0) (Ramamoorthi & Hanrahan 2001): the relative swing of the Lambertian shading between the lit
    and the unlit side. Independent of the map's frame (a rotation keeps |L_1|).

    Args:
        env: the environment map.
        about_up: count only the part of L_1 across the map's up axis, which is what a spin about up
            moves: a turntable only shows the light turning under a map with a high value (the demo
            picks its turntable lighting by it); a sun overhead scores 0.
    """
    coeffs = project_sh(env, order=1)  # [4, 3], band 1 = (y, z, x) in the map's frame
    luminance = coeffs @ np.array([0.2126, 0.7152, 0.0722])  # Rec. 709, linear
    l0 = float(luminance[0])
    l1 = np.array([luminance[3], luminance[1], luminance[2]])  # (x, y, z)
    if about_up:
        up = np.asarray(get_convention(env.convention).up, float)
        l1 = l1 - (l1 @ up) * up
    if not l0 > 0:
        return 0.0
    a = cosine_lobe_coefficients(1)
    # evaluated at the normal along L_1: Y_0 = 1 / (2 sqrt(pi)), band 1's peak sqrt(3 / (4 pi)),
    # a ratio of sqrt(3)
    return float(a[1] * np.linalg.norm(l1) * math.sqrt(3.0) / (a[0] * l0))


def irradiance_brute_force(env: EnvironmentMap, normals: np.ndarray) -> np.ndarray:
    """Reference twin of `irradiance`: direct quadrature over every pixel (slow, exact up to the grid)."""
    dirs = direction_grid(env.height, env.width, env.convention, env.alignment).reshape(-1, 3)
    omega = np.repeat(row_solid_angle(env.height, env.width, env.alignment), env.width)
    radiance = env.radiance_linear.reshape(-1, 3).astype(np.float64)
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    cos = np.clip(n @ dirs.T, 0, None) * omega[None]
    return (cos @ radiance).reshape(*np.shape(normals)[:-1], 3)
