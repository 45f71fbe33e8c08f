"""Physical skies as HDR lat-long maps: Preetham et al. 1999 and the CIE overcast sky, with a sun disc.

Everything is in the Blender world convention every gaffer map uses: world z up, the map's centre
column looks along +x, u = 0.25 along +y. The sun's **azimuth** is measured clockwise from world +y
seen from above, like Blender's `ShaderNodeTexSky.sun_rotation`: 0 points at +y, 90 degrees at +x.
Read +y as north and +x as east and it is the compass azimuth an ephemeris gives
(`gaffer_envmap.sun_position`).

Models (`SkyModel`):

- "preetham": A. J. Preetham, P. Shirley, B. Smits, *A Practical Analytic Model for Daylight*,
  SIGGRAPH 1999. Luminance Y and chromaticity x, y of each direction follow Perez et al.'s
  all-weather function `F(theta, gamma) = (1 + A e^(B / cos theta)) (1 + C e^(D gamma) + E cos^2 gamma)`,
  scaled so the zenith has the paper's zenith values (appendix A.2): `Y = Y_z F(theta, gamma) /
  F(0, theta_s)`, with A..E linear in the turbidity T and Y_z, x_z, y_z fitted in T and the sun's
  zenith angle theta_s. Y is in kcd/m^2. Valid for T in [2, 10] and the sun above the horizon.
- "cie-overcast": the CIE standard overcast sky (Moon & Spencer 1942), `L(theta) = L_z (1 + 2 cos
  theta) / 3`, with the zenith luminance of Krochmann & Seidl 1974, `L_z = 0.123 + 8.6 sin(h_s)`
  kcd/m^2 (h_s: the sun's elevation); neutral (D65) colour and no visible sun.

The sun (preetham only) is a uniform disc of angular diameter 0.53 degrees whose radiance is the
extraterrestrial solar illuminance (133.8 klx; Darula, Kittler & Gueymard 2005) over the disc's solid
angle, attenuated per channel by Rayleigh and aerosol extinction along the Kasten & Young (1989) air
mass: `tau(lambda) = 0.008735 lambda^-4.08 + beta lambda^-1.3` with Preetham's `beta = 0.04608 T -
0.04586` (appendix A.3, lambda in micrometres), at 610, 550 and 465 nm for R, G, B. At noon with T = 3
that is about 100 klx of direct light, as measured on clear days. Its power goes into the pixels the
disc falls in, so it is kept exactly at any width (`gaffer_envmap._disc`).

Below the horizon is a Lambertian ground of albedo rho: `L = rho E_h / pi`, with E_h the horizontal
irradiance of the sky and the sun (computed on a fixed 64 x 128 grid, so the ground does not change
with the output width).

With the sun below the horizon (dawn, dusk, night), which Preetham's fit does not cover, the sky is
the sky of a sun on the horizon at the same azimuth, dimmed by a decade every 2.5 degrees of depression
(about 500 lx at sunset to 3 lx at -6 degrees, the end of civil twilight, as measured) and shifted
towards blue, over a floor of moonless night sky (0.2 mcd/m^2). This twilight extension is ours, not
from a paper: it only keeps such maps plausible.

Units: linear Rec.709 RGB whose luminance (0.2126 R + 0.7152 G + 0.0722 B) is in kcd/m^2, times
`2 ** exposure_ev`. The default exposure, -3 EV (1.0 = 8 kcd/m^2), puts a clear daytime sky near the
brightness of the bundled HDRIs; `exposure_ev=0` gives absolute units.
"""

import math
from dataclasses import dataclass
from typing import Literal, assert_never, get_args

import numpy as np

from gaffer_envmap._disc import cap_solid_angle, splat_disc
from gaffer_envmap.conventions import (
    direction_grid,
    pixel_center_uv,
    row_solid_angle,
    uv_to_direction,
)
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ParameterError

__all__ = [
    "DEFAULT_EXPOSURE_EV",
    "DEFAULT_GROUND_ALBEDO",
    "DEFAULT_TURBIDITY",
    "SKY_MODELS",
    "SUN_ANGULAR_DIAMETER_DEG",
    "TURBIDITY_RANGE",
    "SkyConfig",
    "SkyModel",
    "SunPosition",
    "cie_overcast_sky",
    "preetham_sky",
    "sky_envmap",
    "sun_direction",
    "sun_radiance",
]

SkyModel = Literal["preetham", "cie-overcast"]
"""The sky models `sky_envmap` draws (see the module docstring)."""
SKY_MODELS: tuple[str, ...] = get_args(SkyModel)

SUN_ANGULAR_DIAMETER_DEG = 0.53
"""Apparent diameter of the sun's disc (0.524-0.542 degrees over the year)."""
EXTRATERRESTRIAL_ILLUMINANCE_KCD = 133.8
"""Luminous solar constant, klx (Darula, Kittler & Gueymard 2005): kcd/m^2 times sr."""
TURBIDITY_RANGE = (2.0, 10.0)
"""Turbidities Preetham's fit covers (below about 1.7 its luminance turns negative near the zenith)."""
DEFAULT_TURBIDITY = 3.0
DEFAULT_GROUND_ALBEDO = 0.2
DEFAULT_EXPOSURE_EV = -3.0
"""Default `exposure_ev`: 1.0 in the map = 8 kcd/m^2 (see the module docstring)."""

_LUMA = np.array([0.2126, 0.7152, 0.0722])
# CIE XYZ -> linear Rec.709 (sRGB primaries, D65 white)
_XYZ_TO_REC709 = np.array(
    [
        [3.2404542, -1.5371385, -0.4985314],
        [-0.9692660, 1.8760108, 0.0415560],
        [0.0556434, -0.2040259, 1.0572252],
    ]
)
_CHANNEL_WAVELENGTH_UM = np.array([0.610, 0.550, 0.465])
_NIGHT_SKY_KCD = 2e-7
_NIGHT_TINT = np.array([0.55, 0.75, 1.6])
_BLUE_HOUR_TINT = np.array([0.7, 0.9, 1.5])
_TWILIGHT_DEG_PER_DECADE = 2.5
_IRRADIANCE_GRID_HEIGHT = 64


def _unit_luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb / float(rgb @ _LUMA)


def _finite(name: str, value: object) -> float:
    try:
        x = float(value)  # type: ignore[arg-type]  # anything float() refuses is reported below
    except (TypeError, ValueError) as exc:
        raise ParameterError(f"`{name}` must be a number, got {value!r}.") from exc
    if not math.isfinite(x):
        raise ParameterError(f"`{name}` must be a finite number, got {value!r}.")
    return x


def sun_direction(elevation_deg: float | int, azimuth_deg: float | int) -> np.ndarray:
    """Unit direction `[3]` (Blender world, z up) towards a sun at this elevation and azimuth.

    Azimuth runs clockwise from +y seen from above (Blender's `sun_rotation`): 0 -> +y, 90 -> +x.

    Example:
        >>> np.round(sun_direction(0.0, 90.0), 6).tolist()
        [1.0, 0.0, 0.0]
    """
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])


@dataclass(frozen=True, kw_only=True)
class SunPosition:
    """Where the sun is, as Blender's sky texture and an ephemeris say it.

    Attributes:
        elevation_deg: degrees above the horizon, in [-90, 90] (negative: below it).
        azimuth_deg: degrees clockwise from world +y seen from above, stored in [0, 360).

    Raises:
        ParameterError: a non-finite value or an elevation outside [-90, 90].

    Example:
        >>> SunPosition(elevation_deg=30, azimuth_deg=-90).azimuth_deg
        270.0
    """

    elevation_deg: float | int
    azimuth_deg: float | int

    def __post_init__(self) -> None:
        el = _finite("sun elevation", self.elevation_deg)
        az = _finite("sun azimuth", self.azimuth_deg)
        if not -90.0 <= el <= 90.0:
            raise ParameterError(
                f"`sun elevation` is {el} degrees; pass a value in [-90, 90] (0 = on the horizon)."
            )
        object.__setattr__(self, "elevation_deg", el)
        object.__setattr__(self, "azimuth_deg", az % 360.0)

    @property
    def direction(self) -> np.ndarray:
        """`[3]` unit vector towards the sun (Blender world, z up)."""
        return sun_direction(self.elevation_deg, self.azimuth_deg)


def _rgb_triple(name: str, value: object) -> tuple[float, float, float]:
    if not isinstance(value, tuple | list | np.ndarray):
        raise ParameterError(f"`{name}` must be 3 values (R, G, B), got {value!r}.")
    vals = tuple(_finite(name, v) for v in value)
    if len(vals) != 3:
        raise ParameterError(f"`{name}` needs 1 or 3 values, got {len(vals)}.")
    return vals  # type: ignore[return-value]


@dataclass(frozen=True, kw_only=True)
class SkyConfig:
    """Everything `sky_envmap` needs, checked on construction.

    Attributes:
        sun: the sun's position.
        model: "preetham" (clear to hazy skies, a sun disc) or "cie-overcast" (no visible sun).
        turbidity: haze, Preetham's T in [2, 10]: 2 very clear, 3 clear, 6 hazy, 10 thick haze.
            Used by "preetham" only.
        ground_albedo: reflectance (R, G, B) of the ground below the horizon, in [0, 1].
        exposure_ev: scale of the map, `2 ** exposure_ev` (0: absolute kcd/m^2 luminance).
        tint_rgb: a colour multiplied into the whole map (warm / cool); luminance-neutral by
            convention of its callers, not enforced.
        sun_disc: draw the sun's disc (preetham only).

    Raises:
        ParameterError: a value out of range, named in the message.
    """

    sun: SunPosition
    model: SkyModel = "preetham"
    turbidity: float | int = DEFAULT_TURBIDITY
    ground_albedo: tuple[float, float, float] = (
        DEFAULT_GROUND_ALBEDO,
        DEFAULT_GROUND_ALBEDO,
        DEFAULT_GROUND_ALBEDO,
    )
    exposure_ev: float | int = DEFAULT_EXPOSURE_EV
    tint_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)
    sun_disc: bool = True

    def __post_init__(self) -> None:
        if self.model not in SKY_MODELS:
            raise ParameterError(
                f"`model` {self.model!r} is unknown; use one of: {', '.join(SKY_MODELS)}."
            )
        t = _finite("turbidity", self.turbidity)
        lo, hi = TURBIDITY_RANGE
        if not lo <= t <= hi:
            raise ParameterError(
                f"`turbidity` is {t}; pass a value in [{lo:g}, {hi:g}] (2 very clear, 3 clear, "
                "6 hazy, 10 thick haze), the range Preetham's model was fitted on."
            )
        albedo = _rgb_triple("ground albedo", self.ground_albedo)
        if not all(0.0 <= a <= 1.0 for a in albedo):
            raise ParameterError(f"`ground albedo` is {albedo}; pass values in [0, 1].")
        ev = _finite("exposure", self.exposure_ev)
        if not -40.0 <= ev <= 40.0:
            raise ParameterError(f"`exposure` is {ev} EV; pass a value in [-40, 40].")
        tint = _rgb_triple("tint", self.tint_rgb)
        if not all(0.0 < c <= 10.0 for c in tint):
            raise ParameterError(f"`tint` is {tint}; pass values in (0, 10].")
        object.__setattr__(self, "turbidity", t)
        object.__setattr__(self, "ground_albedo", albedo)
        object.__setattr__(self, "exposure_ev", ev)
        object.__setattr__(self, "tint_rgb", tint)

    def describe(self) -> str:
        """One line: model, sun, turbidity, ground, exposure."""
        parts = [
            self.model,
            f"sun elevation {self.sun.elevation_deg:.1f} deg, azimuth {self.sun.azimuth_deg:.1f} deg",
        ]
        if self.model == "preetham":
            parts.append(f"turbidity {self.turbidity:g}")
        albedo = self.ground_albedo
        shown = f"{albedo[0]:g}" if len(set(albedo)) == 1 else ",".join(f"{a:g}" for a in albedo)
        parts.append(f"ground albedo {shown}")
        parts.append(f"exposure {self.exposure_ev:+g} EV")
        if self.tint_rgb != (1.0, 1.0, 1.0):
            parts.append("tint " + ",".join(f"{c:.2f}" for c in self.tint_rgb))
        return ", ".join(parts)


# ---------------------------------------------------------------------------------------------
# Preetham et al. 1999


def _perez(
    cos_theta: np.ndarray | float, gamma: np.ndarray | float, coeffs: tuple[float, ...]
) -> np.ndarray:
    """Perez et al. 1993 all-weather distribution F(theta, gamma) (Preetham eq. 3)."""
    a, b, c, d, e = coeffs
    # B < 0 for every T >= 2, so e^(B / cos theta) -> 0 at the horizon; keep the division finite
    return np.asarray(
        (1.0 + a * np.exp(b / np.maximum(cos_theta, 1e-4)))
        * (1.0 + c * np.exp(d * gamma) + e * np.cos(gamma) ** 2)
    )


def _preetham_coefficients(t: float) -> tuple[tuple[float, ...], ...]:
    """(Y, x, y) Perez coefficients A..E as linear functions of turbidity (Preetham appendix A.2)."""
    y_lum = (
        0.1787 * t - 1.4630,
        -0.3554 * t + 0.4275,
        -0.0227 * t + 5.3251,
        0.1206 * t - 2.5771,
        -0.0670 * t + 0.3703,
    )
    x_chr = (
        -0.0193 * t - 0.2592,
        -0.0665 * t + 0.0008,
        -0.0004 * t + 0.2125,
        -0.0641 * t - 0.8989,
        -0.0033 * t + 0.0452,
    )
    y_chr = (
        -0.0167 * t - 0.2608,
        -0.0950 * t + 0.0092,
        -0.0079 * t + 0.2102,
        -0.0441 * t - 1.6537,
        -0.0109 * t + 0.0529,
    )
    return y_lum, x_chr, y_chr


def _preetham_zenith(t: float, theta_s: float) -> tuple[float, float, float]:
    """Zenith luminance Y_z (kcd/m^2) and chromaticity x_z, y_z (Preetham appendix A.2)."""
    chi = (4.0 / 9.0 - t / 120.0) * (math.pi - 2.0 * theta_s)
    y_z = (4.0453 * t - 4.9710) * math.tan(chi) - 0.2155 * t + 2.4192
    turb = np.array([t * t, t, 1.0])
    angle = np.array([theta_s**3, theta_s**2, theta_s, 1.0])
    x_mat = np.array(
        [
            [0.00166, -0.00375, 0.00209, 0.0],
            [-0.02903, 0.06377, -0.03202, 0.00394],
            [0.11693, -0.21196, 0.06052, 0.25886],
        ]
    )
    y_mat = np.array(
        [
            [0.00275, -0.00610, 0.00317, 0.0],
            [-0.04214, 0.08970, -0.04153, 0.00516],
            [0.15346, -0.26756, 0.06670, 0.26688],
        ]
    )
    return y_z, float(turb @ x_mat @ angle), float(turb @ y_mat @ angle)


def _xyy_to_rec709(
    big_y: np.ndarray | float, x: np.ndarray | float, y: np.ndarray | float
) -> np.ndarray:
    """CIE xyY -> linear Rec.709 RGB `[..., 3]` (out-of-gamut negatives clipped to 0)."""
    y_safe = np.maximum(y, 1e-6)
    xyz = np.stack([x * big_y / y_safe, big_y, (1.0 - x - y) * big_y / y_safe], axis=-1)
    return np.clip(xyz @ _XYZ_TO_REC709.T, 0.0, None)


def preetham_sky(dirs: np.ndarray, sun_dir: np.ndarray, turbidity: float | int) -> np.ndarray:
    """Preetham sky radiance `[..., 3]` (linear Rec.709, luminance in kcd/m^2) for directions `[..., 3]`.

    Directions below the horizon get the horizon's value of their azimuth; the sun must be at or
    above the horizon (`sun_dir[2] >= 0`), where the fit holds. No sun disc.

    Args:
        dirs: `[..., 3]` unit view directions, Blender world (z up).
        sun_dir: `[3]` unit direction towards the sun, `sun_dir[2] >= 0`.
        turbidity: Preetham's T, in `TURBIDITY_RANGE`.

    Raises:
        ParameterError: the sun is below the horizon or T is out of range.

    Example:
        >>> rgb = preetham_sky(np.array([0.0, 0.0, 1.0]), sun_direction(60, 180), 3.0)
        >>> bool(rgb[2] > rgb[0])  # a blue zenith
        True
    """
    if not TURBIDITY_RANGE[0] <= turbidity <= TURBIDITY_RANGE[1]:
        raise ParameterError(f"`turbidity` is {turbidity}; pass a value in {TURBIDITY_RANGE}.")
    sun = np.asarray(sun_dir, np.float64)
    if sun[2] < -1e-9:
        raise ParameterError("`sun_dir` is below the horizon; Preetham's fit needs z >= 0.")
    theta_s = math.acos(min(max(float(sun[2]), 0.0), 1.0))
    d = np.asarray(dirs, np.float64)
    cos_theta = np.asarray(np.clip(d[..., 2], 0.0, 1.0))
    # below the horizon: the horizon point of the same azimuth (the caller draws the ground there)
    horizontal = np.linalg.norm(d[..., :2], axis=-1, keepdims=True)
    d_up = np.where(d[..., 2:3] < 0.0, d * [1.0, 1.0, 0.0] / np.maximum(horizontal, 1e-12), d)
    gamma = np.asarray(np.arccos(np.clip(d_up @ sun, -1.0, 1.0)))
    coeffs = _preetham_coefficients(turbidity)
    zenith = _preetham_zenith(turbidity, theta_s)
    # each of Y, x, y = its zenith value * F(theta, gamma) / F(0, theta_s)  (Preetham eq. 4)
    y_lum, x_chr, y_chr = (
        z * _perez(cos_theta, gamma, c) / _perez(np.array(1.0), np.array(theta_s), c)
        for z, c in zip(zenith, coeffs, strict=True)
    )
    return _xyy_to_rec709(np.maximum(y_lum, 0.0), x_chr, y_chr)


def cie_overcast_sky(dirs: np.ndarray, sun_elevation_deg: float | int) -> np.ndarray:
    """CIE standard overcast sky `[..., 3]` (neutral; luminance in kcd/m^2) for directions `[..., 3]`.

    `L = L_z (1 + 2 cos theta) / 3` (Moon & Spencer 1942), `L_z = 0.123 + 8.6 sin(h_s)` kcd/m^2
    (Krochmann & Seidl 1974) for a sun at elevation h_s >= 0. Directions below the horizon get the
    horizon's value.

    Example:
        >>> round(float(cie_overcast_sky(np.array([0.0, 0.0, 1.0]), 90.0)[1]), 4)  # L_z, sun overhead
        8.723
    """
    h_s = math.radians(max(sun_elevation_deg, 0.0))
    l_z = 0.123 + 8.6 * math.sin(h_s)
    cos_theta = np.clip(np.asarray(dirs, np.float64)[..., 2], 0.0, 1.0)
    lum = l_z * (1.0 + 2.0 * cos_theta) / 3.0
    return np.repeat(lum[..., None], 3, axis=-1)


def _air_mass(elevation_deg: float) -> float:
    """Relative optical air mass (Kasten & Young 1989), finite down to the horizon (about 38)."""
    h = max(elevation_deg, 0.0)
    return 1.0 / (math.sin(math.radians(h)) + 0.50572 * (h + 6.07995) ** -1.6364)


def sun_radiance(elevation_deg: float | int, turbidity: float | int) -> np.ndarray:
    """Radiance `[3]` of the sun's disc seen from the ground (linear Rec.709, kcd/m^2 luminance).

    The extraterrestrial disc (133.8 klx over a 0.53-degree disc, white) times the per-channel
    transmittance `exp(-m tau(lambda))` of Rayleigh and aerosol extinction (module docstring). Zero
    below the horizon.

    Example:
        >>> rgb = sun_radiance(60.0, 3.0) * (math.pi * math.radians(0.265) ** 2)  # direct normal
        >>> 90 < float(rgb @ _LUMA) < 110  # klx, as on a clear day
        True
    """
    if elevation_deg < 0.0:
        return np.zeros(3)
    omega = cap_solid_angle(math.radians(SUN_ANGULAR_DIAMETER_DEG / 2.0))
    beta = 0.04608 * turbidity - 0.04586  # Angstrom turbidity coefficient (Preetham A.3)
    lam = _CHANNEL_WAVELENGTH_UM
    tau = 0.008735 * lam**-4.08 + beta * lam**-1.3
    return (EXTRATERRESTRIAL_ILLUMINANCE_KCD / omega) * np.exp(-_air_mass(elevation_deg) * tau)


def _twilight(elevation_deg: float) -> tuple[float, np.ndarray]:
    """(gain, tint) of a sky whose sun is `elevation_deg` below the horizon (ours, not a paper's)."""
    if elevation_deg >= 0.0:
        return 1.0, np.ones(3)
    gain = 10.0 ** (elevation_deg / _TWILIGHT_DEG_PER_DECADE)
    blend = min(-elevation_deg / 6.0, 1.0)  # full blue-hour colour at the end of civil twilight
    tint = (1.0 - blend) * np.ones(3) + blend * _unit_luminance(_BLUE_HOUR_TINT)
    return gain, tint


def _sky_without_sun(dirs: np.ndarray, config: SkyConfig) -> np.ndarray:
    """Sky radiance `[..., 3]` in kcd/m^2 (upper hemisphere values; no disc, no ground, no exposure)."""
    el = config.sun.elevation_deg
    gain, tint = _twilight(el)
    model = config.model
    if model == "preetham":
        sun_up = sun_direction(max(el, 0.0), config.sun.azimuth_deg)
        sky = preetham_sky(dirs, sun_up, config.turbidity)
    elif model == "cie-overcast":
        sky = cie_overcast_sky(dirs, el)
    else:
        assert_never(model)
    night = _NIGHT_SKY_KCD * _unit_luminance(_NIGHT_TINT)
    return sky * (gain * tint) + night


def sky_envmap(config: SkyConfig, width: int = 512) -> EnvironmentMap:
    """A physical sky as a lat-long `EnvironmentMap` (Blender convention, `[width/2, width, 3]`).

    Args:
        config: the sky (sun, model, turbidity, ground, exposure, tint).
        width: columns of the map, even, in [8, 16384]; height = width / 2.

    Returns:
        float32 non-negative radiance; `metadata` records the model, sun and turbidity.

    Raises:
        ParameterError: `width` odd or out of range.

    Example:
        >>> env = sky_envmap(SkyConfig(sun=SunPosition(elevation_deg=30, azimuth_deg=90)), width=64)
        >>> env.radiance_linear.shape
        (32, 64, 3)
    """
    if isinstance(width, bool) or not isinstance(width, int | np.integer):
        raise ParameterError(f"`width` must be an integer, got {width!r}.")
    if width % 2 or not 8 <= width <= 16384:
        raise ParameterError(f"`width` is {width}; pass an even number in [8, 16384].")
    width = int(width)
    height = width // 2
    sun_rgb = (
        sun_radiance(config.sun.elevation_deg, config.turbidity)
        if config.model == "preetham"
        else np.zeros(3)
    )
    # Ground: Lambertian, lit by the sky's and the sun's horizontal irradiance
    gh = _IRRADIANCE_GRID_HEIGHT
    grid = direction_grid(gh, 2 * gh)[: gh // 2]  # upper hemisphere rows
    omega = row_solid_angle(gh, 2 * gh)[: gh // 2, None, None]
    e_sky = (_sky_without_sun(grid, config) * grid[..., 2:3] * omega).sum(axis=(0, 1))  # [3]
    sun_omega = cap_solid_angle(math.radians(SUN_ANGULAR_DIAMETER_DEG / 2.0))
    e_sun = sun_rgb * sun_omega * max(math.sin(math.radians(config.sun.elevation_deg)), 0.0)
    ground = np.asarray(config.ground_albedo) * (e_sky + e_sun) / math.pi
    # the sky in blocks of rows: float64 temporaries of a whole 8192-wide map would need gigabytes
    radiance = np.empty((height, width, 3), np.float32)
    u, v = pixel_center_uv(height, width)
    step = max(1, (1 << 20) // width)
    for r0 in range(0, height, step):
        uu, vv = np.meshgrid(u, v[r0 : r0 + step])
        dirs = uv_to_direction(uu, vv)  # [rows, We, 3]
        block = np.where(dirs[..., 2:3] < 0.0, ground, _sky_without_sun(dirs, config))
        radiance[r0 : r0 + step] = block
    if config.sun_disc and sun_rgb.any():
        splat_disc(
            radiance,
            config.sun.direction,
            math.radians(SUN_ANGULAR_DIAMETER_DEG / 2.0),
            sun_rgb,
            above_horizon_only=True,
        )
    radiance *= (np.asarray(config.tint_rgb) * 2.0**config.exposure_ev).astype(np.float32)
    return EnvironmentMap(
        radiance_linear=radiance,
        metadata={
            "gaffer:sky_model": config.model,
            "gaffer:sun_elevation_deg": f"{config.sun.elevation_deg:.4f}",
            "gaffer:sun_azimuth_deg": f"{config.sun.azimuth_deg:.4f}",
            "gaffer:turbidity": f"{config.turbidity:g}",
            "gaffer:exposure_ev": f"{config.exposure_ev:g}",
            "gaffer:units": "luminance in kcd/m^2 times 2**exposure_ev",
        },
    )
