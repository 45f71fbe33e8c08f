"""Power-exact splatting of a small uniform disc of light (a sun, a studio light) onto a lat-long grid.

A 0.53-degree sun covers less than one pixel of a 512-wide map (0.7 degrees a pixel), so evaluating
the disc at pixel centres would drop it or make its power depend on where the centres fall. Instead
the disc (a spherical cap of angular radius r about `centre`) is cut into K equal-solid-angle cells
on a Fibonacci spiral; each cell carries `L * Omega_cap / K` of power into the pixel its centre falls
in, and the pixel's radiance grows by that power over the pixel's solid angle. The map then holds
exactly the cap's power `L * Omega_cap` (to float round-off), however small the disc, and a large disc
comes out as a disc with a staircase edge.
"""

import math

import numpy as np

from gaffer_envmap.conventions import direction_to_uv, row_solid_angle

__all__ = ["cap_solid_angle", "splat_disc"]

_GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def cap_solid_angle(radius_rad: float) -> float:
    """Solid angle (sr) of a spherical cap of angular radius `radius_rad`: 2 pi (1 - cos r)."""
    # 2 sin^2(r/2) = 1 - cos r, without the cancellation of 1 - cos r for r ~ 0.005
    return 4.0 * math.pi * math.sin(0.5 * radius_rad) ** 2


def _frame(centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to `centre` and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(centre[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    a = np.cross(centre, helper)
    a /= np.linalg.norm(a)
    return a, np.cross(centre, a)


def cap_samples(centre: np.ndarray, radius_rad: float, count: int) -> np.ndarray:
    """`[count, 3]` unit directions, one per equal-solid-angle cell of the cap (Fibonacci spiral)."""
    k = np.arange(count) + 0.5
    cos_psi = 1.0 - (k / count) * (1.0 - math.cos(radius_rad))  # uniform in cos: equal areas
    sin_psi = np.sqrt(np.clip(1.0 - cos_psi**2, 0.0, None))
    phi = np.arange(count) * _GOLDEN_ANGLE
    a, b = _frame(centre)
    return (
        cos_psi[:, None] * centre
        + (sin_psi * np.cos(phi))[:, None] * a
        + (sin_psi * np.sin(phi))[:, None] * b
    )


def splat_disc(
    radiance: np.ndarray,
    centre: np.ndarray,
    radius_rad: float,
    radiance_rgb: np.ndarray,
    *,
    above_horizon_only: bool = False,
) -> float:
    """Add a uniform disc of radiance `radiance_rgb` to a Blender-convention map, in place.

    Args:
        radiance: `[He, 2*He, 3]` float map (Blender convention, centre-aligned), modified in place.
        centre: `[3]` unit direction of the disc's centre (world z up).
        radius_rad: angular radius of the disc, radians, > 0.
        radiance_rgb: `[3]` radiance of the disc.
        above_horizon_only: drop the part of the disc below the horizon (z < 0), which the ground
            hides (a setting sun).

    Returns:
        The fraction of the disc that was added (1.0 unless `above_horizon_only` cut some off).
    """
    height, width = radiance.shape[:2]
    omega_cap = cap_solid_angle(radius_rad)
    omega_row = row_solid_angle(height, width)
    # >= 64 cells per pixel the disc covers where it is (pixels shrink as cos(elevation)), >= 256 in all
    centre_row = min(
        int(math.acos(float(np.clip(centre[2], -1.0, 1.0))) / math.pi * height), height - 1
    )
    pixel_there = float(omega_row[centre_row])
    count = int(min(max(256, 64 * omega_cap / max(pixel_there, 1e-12)), 2_000_000))
    dirs = cap_samples(np.asarray(centre, np.float64), radius_rad, count)
    if above_horizon_only:
        dirs = dirs[dirs[:, 2] >= 0.0]
    if len(dirs) == 0:
        return 0.0
    u, v = direction_to_uv(dirs)
    col = np.minimum((np.asarray(u) * width).astype(np.int64), width - 1)
    row = np.minimum((np.asarray(v) * height).astype(np.int64), height - 1)
    # only the pixels the disc touches (a full-size count would cost 2 x 270 MB at 8192 wide)
    pixels, hits = np.unique(row * width + col, return_counts=True)
    rows, cols = np.divmod(pixels, width)
    # power per cell = L * Omega_cap / K; radiance = power / Omega_pixel
    gain = hits * (omega_cap / count) / omega_row[rows]  # [P]
    radiance[rows, cols] += gain[:, None] * np.asarray(radiance_rgb, np.float64)
    return len(dirs) / count
