"""Integrals over the sphere: power, mean light direction, and a summary for `gaffer-envmap info`."""

from dataclasses import dataclass

import numpy as np

from gaffer_envmap.conventions import direction_grid, get_convention, row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap


def total_power(env: EnvironmentMap) -> np.ndarray:
    """`[3]` radiant power per channel, sum(L * Omega) (W/sr * sr units of the map), in float64."""
    omega = row_solid_angle(env.height, env.width, env.alignment)
    return np.einsum("hwc,h->c", env.radiance_linear.astype(np.float64), omega)


def first_moment(env: EnvironmentMap) -> np.ndarray:
    """`[3]` mean light vector integral(L(w) w dw) of the luminance-weighted map (Rec.709 Y), in the
    convention's own world frame. Rotating the map by R rotates this by R."""
    y = env.radiance_linear.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])
    omega = row_solid_angle(env.height, env.width, env.alignment)
    dirs = direction_grid(env.height, env.width, env.convention, env.alignment)
    return np.einsum("hw,h,hwc->c", y, omega, dirs)


def mean_light_direction(env: EnvironmentMap) -> np.ndarray:
    """`[3]` unit mean light direction (normalised first moment); zeros for an empty or uniform map."""
    m = first_moment(env)
    n = np.linalg.norm(m)
    return m / n if n > 0 else np.zeros(3)


@dataclass(frozen=True)
class EnvmapInfo:
    """What `gaffer-envmap info` prints."""

    height: int
    width: int
    convention: str
    up_axis: tuple[float, float, float]
    min_value: float
    max_value: float
    mean_value: float
    nan_count: int
    inf_count: int
    negative_count: int
    power_rgb: tuple[float, float, float]
    dominant_direction: tuple[float, float, float]
    brightest_pixel_direction: tuple[float, float, float]


def describe(env: EnvironmentMap, raw: np.ndarray | None = None) -> EnvmapInfo:
    """Summary statistics; `raw` (the unsanitised array) feeds the NaN/Inf/negative counts when given."""
    arr = env.radiance_linear if raw is None else raw
    finite = np.where(np.isfinite(env.radiance_linear), env.radiance_linear, 0.0)
    y = finite @ np.array([0.2126, 0.7152, 0.0722])
    i, j = np.unravel_index(int(np.argmax(y)), y.shape)
    dirs = direction_grid(env.height, env.width, env.convention, env.alignment)
    clean = env.with_radiance(finite)
    raw_finite = np.asarray(arr)[np.isfinite(arr)]
    return EnvmapInfo(
        height=env.height,
        width=env.width,
        convention=env.convention,
        up_axis=tuple(float(x) for x in get_convention(env.convention).up),  # type: ignore[arg-type]
        # the range of the finite values as stored (`info` used to say 0.0 for a map whose
        # negatives had been zeroed on read)
        min_value=float(raw_finite.min()) if raw_finite.size else 0.0,
        max_value=float(raw_finite.max()) if raw_finite.size else 0.0,
        mean_value=float(finite.mean()),
        nan_count=int(np.isnan(arr).sum()),
        inf_count=int(np.isinf(arr).sum()),
        negative_count=int((arr < 0).sum()),
        power_rgb=tuple(float(x) for x in total_power(clean)),  # type: ignore[arg-type]
        dominant_direction=tuple(float(x) for x in mean_light_direction(clean)),  # type: ignore[arg-type]
        brightest_pixel_direction=tuple(float(x) for x in dirs[i, j]),  # type: ignore[arg-type]
    )
