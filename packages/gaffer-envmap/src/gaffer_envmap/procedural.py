"""Procedural HDR environment maps: random skies, grounds and lights for training-data variety.

Eight bundled HDRIs are too few lightings to learn relighting from (a model fits the training maps
rather than light in general; gaffer-tiny model card). `procedural_envmap(seed)` draws a map from a
simple, physically plausible family that covers what real captures hold at the scale a small model
sees: a sky gradient from horizon to zenith, a darker ground below the horizon, and one to four
emitters (a small hard "sun" or a broad soft "window") of random colour and size, with the emitters
carrying 20-95% of the total power. Exposure is log-uniform over the range of the bundled maps
(mean radiance 0.1-1.0).

Every map is a function of its seed alone, so a training recipe names its lighting by seeds.
"""

import math

import numpy as np

from gaffer_envmap.conventions import direction_grid, row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap

__all__ = ["procedural_envmap"]


def _random_colour(rng: np.random.Generator, saturation_max: float) -> np.ndarray:
    """A linear RGB colour of luminance ~1 with a random hue and bounded saturation."""
    import colorsys

    rgb = np.array(colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.0, saturation_max), 1.0))
    lum = float(rgb @ np.array([0.2126, 0.7152, 0.0722]))
    return rgb / max(lum, 1e-6)


def procedural_envmap(seed: int, height: int = 128) -> EnvironmentMap:
    """A random HDR lat-long map (Blender convention, z up) determined by `seed`.

    Args:
        seed: any non-negative integer; the same seed gives the same map.
        height: rows of the map (width = 2 * height), >= 8.

    Returns:
        An `EnvironmentMap` of non-negative finite float32 radiance.

    Raises:
        ValueError: `seed` < 0 or `height` < 8.

    Example:
        >>> env = procedural_envmap(0, height=16)
        >>> env.radiance_linear.shape, bool((env.radiance_linear >= 0).all())
        ((16, 32, 3), True)
    """
    if seed < 0:
        raise ValueError(f"`seed` is {seed}; pass a non-negative integer.")
    if height < 8:
        raise ValueError(f"`height` is {height}; pass 8 or more rows.")
    rng = np.random.default_rng([seed, 0x9AFFE2])
    dirs = direction_grid(height, 2 * height)  # [H, W, 3] float64, z up
    z = dirs[..., 2:3]
    # Sky: horizon -> zenith blend; ground: a dim tint (a diffuse floor lit by the sky)
    horizon = _random_colour(rng, 0.35) * rng.uniform(0.5, 1.5)
    zenith = _random_colour(rng, 0.7) * rng.uniform(0.2, 1.2)
    ground = _random_colour(rng, 0.5) * rng.uniform(0.05, 0.6)
    up = np.clip(z, 0.0, 1.0) ** rng.uniform(0.3, 1.5)
    sky = np.where(z >= 0.0, horizon * (1.0 - up) + zenith * up, ground * (1.0 - 0.5 * np.abs(z)))
    radiance = sky.astype(np.float64)
    # Emitters: direction biased to the upper hemisphere, vMF-like falloff exp(k (cos - 1))
    omega = row_solid_angle(height, 2 * height)[:, None, None] * np.ones((1, 2 * height, 1))
    sky_power = float((radiance.mean(-1, keepdims=True) * omega).sum())
    fraction = rng.uniform(0.2, 0.95)
    count = int(rng.integers(1, 5))
    shares = rng.dirichlet(np.ones(count))
    for share in shares:
        elevation = math.asin(rng.uniform(-0.3, 1.0))
        azimuth = rng.uniform(0.0, 2.0 * math.pi)
        centre = np.array(
            [
                math.cos(elevation) * math.cos(azimuth),
                math.cos(elevation) * math.sin(azimuth),
                math.sin(elevation),
            ]
        )
        # angular radius: a hard sun (2-6 deg) or a soft window / softbox (10-40 deg)
        radius = math.radians(rng.uniform(2.0, 6.0) if rng.uniform() < 0.5 else rng.uniform(10, 40))
        # keep the lobe resolvable at this map's pixel size (pi / height per row)
        radius = max(radius, 1.5 * math.pi / height)
        kappa = 1.0 / (1.0 - math.cos(radius))
        lobe = np.exp(kappa * ((dirs @ centre)[..., None] - 1.0))
        lobe_power = float((lobe * omega).sum())
        power = sky_power * fraction / (1.0 - fraction) * share
        radiance = radiance + lobe * _random_colour(rng, 0.6) * (power / max(lobe_power, 1e-12))
    mean = float(radiance.mean())
    exposure = math.exp(rng.uniform(math.log(0.1), math.log(1.0)))
    radiance *= exposure / max(mean, 1e-12)
    return EnvironmentMap(
        radiance_linear=radiance.astype(np.float32),
        metadata={"gaffer:procedural_seed": str(seed)},
    )
