"""Random physically based HDR environment maps: clear and hazy skies with a sun, overcast skies, studios.

Why: `procedural_envmap`'s family (a sky gradient with soft vMF emitters) never holds what real
outdoor captures hold most: a sun whose disc (0.53 deg) carries most of the irradiance over a
Preetham sky, often near the horizon (sunset, sunrise), or a grey studio lit by a few small discs. A
model trained on it and four bundled HDRIs relit the test split's outdoor maps far worse than its
studio-like ones (gaffer-tiny model card, by map). `physical_envmap(seed)` draws from the
physical models this package already has (`gaffer_envmap.sky`, `gaffer_envmap.studio`):

- 55%: Preetham clear-to-hazy sky (turbidity 2-8) with its sun, elevation 1-75 degrees (a third of
  them below 15: low, warm suns), random azimuth and ground albedo;
- 15%: CIE overcast sky (no sun), the sun's elevation setting its brightness;
- 30%: a studio with one to three random lights (softbox, key, spot, rim, fill) of random tint.

Every map is rescaled to a mean radiance log-uniform in [0.1, 1.0], the range `procedural_envmap`
uses (the bundled maps' range), so the two families mix in one training recipe. A function of its seed.
"""

import math
from typing import cast

import numpy as np

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.sky import SkyConfig, SunPosition, sky_envmap
from gaffer_envmap.studio import (
    LIGHT_KINDS,
    LightKind,
    StudioConfig,
    StudioLight,
    default_light,
    studio_envmap,
)

__all__ = ["PHYSICAL_FAMILIES", "physical_envmap"]

PHYSICAL_FAMILIES: tuple[str, ...] = ("preetham", "cie-overcast", "studio")
"""The families `physical_envmap` draws from, in the order of its draw."""

_FAMILY_P = (0.55, 0.15, 0.30)


def _tint(rng: np.random.Generator, spread: float) -> tuple[float, float, float]:
    """A colour of luminance ~1 within `spread` of white (each channel scaled by exp(N(0, spread)))."""
    c = np.exp(rng.normal(0.0, spread, 3))
    c = c / float(c @ np.array([0.2126, 0.7152, 0.0722]))
    return (float(c[0]), float(c[1]), float(c[2]))


def _sky(rng: np.random.Generator, model: str, width: int) -> EnvironmentMap:
    low = rng.uniform() < 1.0 / 3.0
    elevation = rng.uniform(1.0, 15.0) if low else rng.uniform(15.0, 75.0)
    albedo = rng.uniform(0.05, 0.4)
    ground = tuple(float(albedo * g) for g in _tint(rng, 0.15))
    config = SkyConfig(
        sun=SunPosition(elevation_deg=elevation, azimuth_deg=rng.uniform(0.0, 360.0)),
        model="preetham" if model == "preetham" else "cie-overcast",
        turbidity=rng.uniform(2.0, 8.0),
        ground_albedo=(min(ground[0], 1.0), min(ground[1], 1.0), min(ground[2], 1.0)),
        tint_rgb=_tint(rng, 0.05),
    )
    return sky_envmap(config, width=width)


def _studio(rng: np.random.Generator, width: int) -> EnvironmentMap:
    lights = []
    for _ in range(int(rng.integers(1, 4))):
        kind = cast(LightKind, LIGHT_KINDS[int(rng.integers(len(LIGHT_KINDS)))])
        base = default_light(
            kind,
            azimuth_deg=rng.uniform(0.0, 360.0),
            elevation_deg=rng.uniform(-10.0, 80.0),
        )
        lights.append(
            StudioLight(
                kind=base.kind,
                azimuth_deg=base.azimuth_deg,
                elevation_deg=base.elevation_deg,
                radius_deg=float(base.radius_deg) * rng.uniform(0.6, 1.6),
                luminance=float(base.luminance) * math.exp(rng.uniform(-1.0, 1.0)),
                tint_rgb=_tint(rng, 0.25),
            )
        )
    config = StudioConfig(lights=tuple(lights), wall_luminance=rng.uniform(0.02, 0.5))
    return studio_envmap(config, width=width)


def physical_envmap(seed: int, height: int = 128) -> EnvironmentMap:
    """A random physically based HDR lat-long map (Blender convention, z up) determined by `seed`.

    Args:
        seed: any non-negative integer; the same seed gives the same map.
        height: rows of the map (width = 2 * height), >= 8.

    Returns:
        An `EnvironmentMap` of non-negative finite float32 radiance with a mean in [0.1, 1.0];
        `metadata["gaffer:physical_family"]` names its family (`PHYSICAL_FAMILIES`).

    Raises:
        ValueError: `seed` < 0 or `height` < 8.

    Example:
        >>> env = physical_envmap(0, height=16)
        >>> env.radiance_linear.shape, env.metadata["gaffer:physical_family"] in PHYSICAL_FAMILIES
        ((16, 32, 3), True)
    """
    if seed < 0:
        raise ValueError(f"`seed` is {seed}; pass a non-negative integer.")
    if height < 8:
        raise ValueError(f"`height` is {height}; pass 8 or more rows.")
    rng = np.random.default_rng([int(seed), 0x5C7])
    family = PHYSICAL_FAMILIES[int(rng.choice(len(PHYSICAL_FAMILIES), p=_FAMILY_P))]
    width = 2 * int(height)
    env = _studio(rng, width) if family == "studio" else _sky(rng, family, width)
    radiance = env.radiance_linear.astype(np.float64)
    exposure = math.exp(rng.uniform(math.log(0.1), math.log(1.0)))
    radiance *= exposure / max(float(radiance.mean()), 1e-12)
    return EnvironmentMap(
        radiance_linear=radiance.astype(np.float32),
        metadata={
            **env.metadata,
            "gaffer:physical_seed": str(int(seed)),
            "gaffer:physical_family": family,
        },
    )
