"""Procedural photo-studio lighting: a dim grey room with softboxes, key, rim and fill lights.

`gaffer_envmap.procedural` draws random maps for training; this module draws a described one. The
room is a grey cyclorama, brighter overhead than on the floor; each light is a uniform disc of
given angular radius, direction and luminance, splatted power-exactly (`gaffer_envmap._disc`), so a
small spotlight keeps its power at any width.

Directions use the sky's convention (`gaffer_envmap.sky`): azimuth clockwise from world +y seen from
above. For a camera looking along world +y (Blender's front view, `IDENTITY_LAYOUT_W2C`), a light
"from the left" is at azimuth 270 (-x), "from the right" 90 (+x), "from behind" the subject 0 (+y)
and "from the front" (the camera's side) 180 (-y).

Units as in `gaffer_envmap.sky`: luminance in kcd/m^2 times `2 ** exposure_ev`. The default lights
give about 4 klx at the subject from the key, a bright photo studio.
"""

import math
from dataclasses import dataclass, field, replace
from typing import Literal, get_args

import numpy as np

from gaffer_envmap._disc import cap_solid_angle, splat_disc
from gaffer_envmap.conventions import pixel_center_uv
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ParameterError
from gaffer_envmap.sky import DEFAULT_EXPOSURE_EV, sun_direction

__all__ = [
    "LIGHT_KINDS",
    "LightKind",
    "StudioConfig",
    "StudioLight",
    "add_disc_light",
    "default_light",
    "light_irradiance",
    "studio_envmap",
]

LightKind = Literal["softbox", "key", "spot", "rim", "fill"]
"""Kinds of studio light `default_light` knows."""
LIGHT_KINDS: tuple[str, ...] = get_args(LightKind)

# kind -> (angular radius deg, luminance kcd/m^2, default azimuth deg, elevation deg).
# Key, softbox and spot give the same irradiance (about 4.3 klx), from sources of different sizes.
_DEFAULTS: dict[str, tuple[float, float, float, float]] = {
    "softbox": (15.0, 20.0, 225.0, 30.0),
    "key": (8.0, 70.0, 225.0, 35.0),
    "spot": (3.0, 500.0, 225.0, 45.0),
    "rim": (6.0, 85.0, 0.0, 25.0),
    "fill": (20.0, 4.0, 135.0, 15.0),
}


@dataclass(frozen=True, kw_only=True)
class StudioLight:
    """One studio light: a uniform disc.

    Attributes:
        kind: what it is ("softbox", "key", "spot", "rim", "fill"), for messages.
        azimuth_deg: clockwise from world +y seen from above (see the module docstring).
        elevation_deg: above the horizon, [-90, 90].
        radius_deg: angular radius of the disc, (0, 60].
        luminance: kcd/m^2 (before the studio's exposure), > 0.
        tint_rgb: colour of the light (1, 1, 1 = white).

    Raises:
        ParameterError: a value out of range.
    """

    kind: str
    azimuth_deg: float | int
    elevation_deg: float | int
    radius_deg: float | int
    luminance: float | int
    tint_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        for name in ("azimuth_deg", "elevation_deg", "radius_deg", "luminance"):
            if not math.isfinite(float(getattr(self, name))):
                raise ParameterError(f"`{name}` of the {self.kind} light must be finite.")
        if not -90.0 <= self.elevation_deg <= 90.0:
            raise ParameterError(
                f"`elevation_deg` {self.elevation_deg}: pass a value in [-90, 90]."
            )
        if not 0.0 < self.radius_deg <= 60.0:
            raise ParameterError(f"`radius_deg` {self.radius_deg}: pass a value in (0, 60].")
        if not self.luminance > 0.0:
            raise ParameterError(f"`luminance` {self.luminance}: pass a value > 0.")
        object.__setattr__(self, "azimuth_deg", float(self.azimuth_deg) % 360.0)

    @property
    def direction(self) -> np.ndarray:
        """`[3]` unit vector towards the light's centre (Blender world, z up)."""
        return sun_direction(self.elevation_deg, self.azimuth_deg)

    def describe(self) -> str:
        """e.g. "softbox at azimuth 270 deg, elevation 30 deg (15 deg radius)"."""
        return (
            f"{self.kind} at azimuth {self.azimuth_deg:g} deg, elevation {self.elevation_deg:g} deg "
            f"({self.radius_deg:g} deg radius)"
        )


def default_light(
    kind: LightKind,
    azimuth_deg: float | int | None = None,
    elevation_deg: float | int | None = None,
) -> StudioLight:
    """A studio light of a known kind, with that kind's size, brightness and usual placement.

    Example:
        >>> default_light("softbox", azimuth_deg=270).describe()
        'softbox at azimuth 270 deg, elevation 30 deg (15 deg radius)'
    """
    if kind not in _DEFAULTS:
        raise ParameterError(f"`kind` {kind!r} is unknown; use one of: {', '.join(LIGHT_KINDS)}.")
    radius, lum, az, el = _DEFAULTS[kind]
    return StudioLight(
        kind=kind,
        azimuth_deg=az if azimuth_deg is None else azimuth_deg,
        elevation_deg=el if elevation_deg is None else elevation_deg,
        radius_deg=radius,
        luminance=lum,
    )


@dataclass(frozen=True, kw_only=True)
class StudioConfig:
    """A studio: lights in a grey room.

    Attributes:
        lights: the lights (at least one).
        wall_luminance: the room above the horizon, kcd/m^2 (the floor gets half).
        exposure_ev: scale of the map, `2 ** exposure_ev`.
        tint_rgb: colour multiplied into the whole map (warm / cool).

    Raises:
        ParameterError: no light, or a value out of range.
    """

    lights: tuple[StudioLight, ...] = field(
        default_factory=lambda: (default_light("softbox"), default_light("fill"))
    )
    wall_luminance: float | int = 0.25
    exposure_ev: float | int = DEFAULT_EXPOSURE_EV
    tint_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        if not self.lights:
            raise ParameterError("`lights` is empty; a studio needs at least one light.")
        if not (math.isfinite(self.wall_luminance) and self.wall_luminance >= 0.0):
            raise ParameterError(f"`wall_luminance` {self.wall_luminance}: pass a value >= 0.")
        if not (math.isfinite(self.exposure_ev) and -40.0 <= self.exposure_ev <= 40.0):
            raise ParameterError(f"`exposure` is {self.exposure_ev} EV; pass a value in [-40, 40].")
        if len(self.tint_rgb) != 3 or not all(0.0 < c <= 10.0 for c in self.tint_rgb):
            raise ParameterError(f"`tint` is {self.tint_rgb}; pass 3 values in (0, 10].")
        object.__setattr__(self, "lights", tuple(self.lights))

    def with_exposure(self, exposure_ev: float | int) -> "StudioConfig":
        """A copy with another exposure."""
        return replace(self, exposure_ev=exposure_ev)

    def describe(self) -> str:
        """One line: the lights and the exposure."""
        lights = "; ".join(light.describe() for light in self.lights)
        return f"studio: {lights}; exposure {self.exposure_ev:+g} EV"


def studio_envmap(config: StudioConfig, width: int = 512) -> EnvironmentMap:
    """A studio lighting map (Blender convention, `[width/2, width, 3]`).

    Args:
        config: the lights and the room.
        width: columns, even, in [8, 16384]; height = width / 2.

    Returns:
        float32 non-negative radiance; each light holds exactly `luminance * tint * Omega_disc`
        of power (times the exposure), at any width.

    Raises:
        ParameterError: `width` odd or out of range.

    Example:
        >>> env = studio_envmap(StudioConfig(), width=64)
        >>> env.radiance_linear.shape
        (32, 64, 3)
    """
    if isinstance(width, bool) or not isinstance(width, int | np.integer):
        raise ParameterError(f"`width` must be an integer, got {width!r}.")
    if width % 2 or not 8 <= width <= 16384:
        raise ParameterError(f"`width` is {width}; pass an even number in [8, 16384].")
    width = int(width)
    height = width // 2
    z = np.cos(np.pi * pixel_center_uv(height, width)[1])  # [He] row heights (z of each row)
    # cyclorama: brightest overhead, half as bright on the floor, smooth through the horizon
    room = config.wall_luminance * (0.75 + 0.25 * np.clip(z * 2.0, -1.0, 1.0))
    radiance = np.empty((height, width, 3), np.float32)
    radiance[:] = room[:, None, None]
    for light in config.lights:
        splat_disc(
            radiance,
            light.direction,
            math.radians(light.radius_deg),
            light.luminance * np.asarray(light.tint_rgb),
        )
    radiance *= (np.asarray(config.tint_rgb) * 2.0**config.exposure_ev).astype(np.float32)
    return EnvironmentMap(
        radiance_linear=radiance,
        metadata={
            "gaffer:studio_lights": "; ".join(light.describe() for light in config.lights),
            "gaffer:exposure_ev": f"{config.exposure_ev:g}",
            "gaffer:units": "luminance in kcd/m^2 times 2**exposure_ev",
        },
    )


def light_irradiance(light: StudioLight) -> float:
    """Illuminance (klx) the light gives a surface facing it: `luminance * Omega_disc`."""
    return light.luminance * cap_solid_angle(math.radians(light.radius_deg))


def add_disc_light(
    env: EnvironmentMap,
    direction: np.ndarray,
    radius_deg: float,
    irradiance_rgb: np.ndarray | tuple[float, float, float],
) -> EnvironmentMap:
    """A copy of a Blender-convention map with a uniform disc of light added, power-exactly.

    The disc's radiance is `irradiance / Omega_disc`, so a surface facing it receives exactly
    `irradiance_rgb` from it (in the map's units), however few pixels the disc covers
    (`gaffer_envmap._disc`). Used for a key light added to an estimated map
    (`gaffer-diffusion insert --key-light`).

    Args:
        env: the map (Blender convention, centre-aligned).
        direction: `[3]` direction towards the light's centre, world z up (e.g. `sun_direction`).
        radius_deg: angular radius of the disc, degrees, in (0, 90].
        irradiance_rgb: `[3]` irradiance at normal incidence, >= 0.

    Raises:
        ParameterError: another convention or alignment, a bad radius, direction or irradiance.

    Example:
        >>> env = EnvironmentMap(radiance_linear=np.zeros((32, 64, 3), np.float32))
        >>> lit = add_disc_light(env, np.array([0.0, 0.0, 1.0]), 5.0, (2.0, 2.0, 2.0))
        >>> from gaffer_envmap.stats import total_power
        >>> round(float(total_power(lit)[0]), 4)
        2.0
    """
    if env.convention != "blender" or env.alignment != "center":
        raise ParameterError(
            f"`env` is {env.convention!r}/{env.alignment!r}; pass a centre-aligned Blender map."
        )
    d = np.asarray(direction, np.float64)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) == 0:
        raise ParameterError(f"`direction` must be a finite non-zero [3] vector, got {d.tolist()}.")
    if not (math.isfinite(radius_deg) and 0.0 < radius_deg <= 90.0):
        raise ParameterError(f"`radius_deg` is {radius_deg}; pass degrees in (0, 90].")
    e = np.asarray(irradiance_rgb, np.float64)
    if e.shape != (3,) or not np.all(np.isfinite(e)) or (e < 0).any():
        raise ParameterError(f"`irradiance_rgb` must be 3 finite values >= 0, got {e.tolist()}.")
    radiance = np.array(env.radiance_linear, np.float64)
    radius = math.radians(radius_deg)
    splat_disc(radiance, d / np.linalg.norm(d), radius, e / cap_solid_angle(radius))
    return env.with_radiance(radiance.astype(np.float32))
