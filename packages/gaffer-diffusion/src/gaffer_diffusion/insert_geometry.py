"""The geometry and lighting of object insertion (`gaffer_diffusion.insert`), without the model.

Cameras, key lights, the map built from a background photo (`light_from_photo`), the dominant light
(`dominant_light`), placement (`resolve_placement`, `place_object`), the pixel-height shadow
(`cast_shadow_2d`) and the composite (`composite`). It imports torch but not diffusers, so the command
line checks a placement before any model code loads; `gaffer_diffusion.insert` re-exports all of it.
The steps and the geometry are described there.
"""

import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float

from gaffer_diffusion import detail_transfer as dt
from gaffer_diffusion._choices import BACKDROP_FOV_DEG
from gaffer_diffusion.errors import ConfigError, InputValueError
from gaffer_diffusion.photo import Photo, RelitObject
from gaffer_diffusion.preprocess import ALPHA_THRESHOLD
from gaffer_envmap.conventions import direction_grid, row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.poses import IDENTITY_LAYOUT_W2C, W2CBlender
from gaffer_envmap.resample import resize_conservative
from gaffer_envmap.sky import sun_direction
from gaffer_envmap.studio import add_disc_light
from gaffer_envmap.writers import quantize

__all__ = [
    "LEVEL_CAMERA",
    "BackgroundCamera",
    "DominantLight",
    "InsertLighting",
    "KeyLight",
    "ObjectExtent",
    "PlacedObject",
    "Placement",
    "cast_shadow_2d",
    "composite",
    "default_placement",
    "dominant_light",
    "inverse_tone",
    "light_from_photo",
    "object_extent",
    "place_object",
    "resolve_placement",
]

LEVEL_CAMERA = IDENTITY_LAYOUT_W2C
"""The background camera without `--w2c`: level, looking along world +y, world +x to the right."""

LIGHT_FROM_PHOTO_WIDTH = 256
"""Width of the map built from a photo (256 x 128: 1.4 degrees a pixel, finer than the model sees)."""

INVERSE_TONE_PEAK = 8.0
"""Inverse tone curve `L = c / max(1 - c, 1 / peak)` of linear display values c in [0, 1]: inverse
Reinhard (`c = L / (1 + L)`) below c = 1 - 1/peak, then linear up to `peak` at c = 1."""

KEY_STRENGTH = 3.0
"""Default key-light strength: its irradiance on a surface facing it, in multiples of pi times the
mean radiance of the map built from the photo (the irradiance that map's average gives)."""

KEY_SIZE_DEG = 5.0
"""Default angular diameter of the key light, degrees (the sun is 0.53; a small softbox 10-20)."""

DEFAULT_FOOT = (0.5, 5.0 / 6.0)
"""Default `--at`, as fractions of the background's width and height: the centre of its bottom third."""

MIN_HEIGHT_PX = 4.0
"""Smallest `--height` accepted, pixels."""

CONTACT_STRENGTH = 0.5
"""How much of the ambient (non-key) light the contact shadow under the object takes away, at most."""

MIN_FORESHORTENING = 0.05
"""The ground's foreshortening at the foot, at least (a foot on or above the horizon)."""

MAX_SHADOW_LENGTH = 6.0
"""A cast shadow is at most this many object heights long (a light near the horizon)."""

MIN_SHADOW_ELEVATION_DEG = 2.0
"""A dominant light lower than this casts no shadow on the ground (only the contact shadow is left)."""

SHADOW_CUTOFF = 1.0 / 1024.0
"""Darkening below this (under a quarter of an 8-bit step) is dropped: those pixels keep their bytes."""


@dataclass(frozen=True, kw_only=True)
class BackgroundCamera:
    """The background photo's pinhole camera.

    Attributes:
        width: image width, pixels.
        height: image height, pixels.
        fov_deg: horizontal field of view, degrees, in [1, 179].
        w2c: Blender world-to-camera pose (x right, y up, looks along -z; world z up, the ground at
            z = 0). Default: level, looking along world +y.

    Raises:
        ConfigError: a size below 1 or a field of view outside [1, 179] (names `--fov`).
    """

    width: int
    height: int
    fov_deg: float | int = BACKDROP_FOV_DEG
    w2c: W2CBlender = LEVEL_CAMERA

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ConfigError(f"The background is {self.width}x{self.height}; it needs pixels.")
        if not (math.isfinite(self.fov_deg) and 1.0 <= self.fov_deg <= 179.0):
            raise ConfigError(
                f"`--fov` is {self.fov_deg}; pass the background's horizontal field of view in "
                f"degrees, in [1, 179] (default {BACKDROP_FOV_DEG}: a 50 mm lens on 36 mm)."
            )

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: `width / (2 tan(fov / 2))`."""
        return self.width / (2.0 * math.tan(math.radians(self.fov_deg) / 2.0))

    @property
    def forward_world(self) -> np.ndarray:
        """`[3]` viewing direction in the world (the camera's -z)."""
        return -np.asarray(self.w2c.rotation[2], np.float64)

    @property
    def horizon_row(self) -> float:
        """Image row (pixel-edge coordinate) of the horizon: the middle for a level camera, lower
        when the camera looks up."""
        pitch = math.asin(float(np.clip(self.forward_world[2], -1.0, 1.0)))
        return self.height / 2.0 + self.focal_px * math.tan(np.clip(pitch, -1.5, 1.5))

    def ground_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """`(right, forward)`: unit world vectors on the ground plane, to the image's right and away
        from the camera."""
        rot = np.asarray(self.w2c.rotation, np.float64)
        right = rot[0] - rot[0][2] * np.array([0.0, 0.0, 1.0])
        if np.linalg.norm(right) < 1e-9:  # rolled on its side: take the image's up instead
            right = rot[1] - rot[1][2] * np.array([0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        forward = np.cross(np.array([0.0, 0.0, 1.0]), right)
        return right, forward


@dataclass(frozen=True, kw_only=True)
class KeyLight:
    """A key light added to the map built from a photo: a uniform disc of exact power.

    Attributes:
        azimuth_deg: degrees clockwise from world +y seen from above, as `gaffer-envmap sky` and
            Blender's `sun_rotation` (default camera: 0 straight ahead, behind the object, facing
            the camera; 90 from the right; 180 from behind the camera; 270 from the left).
        elevation_deg: degrees above the horizon, in [-90, 90].
        strength: its irradiance on a surface facing it, in multiples of pi times the mean radiance of
            the map it is added to; >= 0.
        size_deg: angular diameter of the disc, degrees, in (0, 90].

    Raises:
        ConfigError: a value out of range (names `--key-light`).
    """

    azimuth_deg: float | int
    elevation_deg: float | int
    strength: float | int = KEY_STRENGTH
    size_deg: float | int = KEY_SIZE_DEG

    def __post_init__(self) -> None:
        vals = (self.azimuth_deg, self.elevation_deg, self.strength, self.size_deg)
        if not all(math.isfinite(v) for v in vals):
            raise ConfigError(f"`--key-light` {vals} holds NaN or Inf; pass finite numbers.")
        if not -90.0 <= self.elevation_deg <= 90.0:
            raise ConfigError(
                f"`--key-light` elevation is {self.elevation_deg}; pass degrees in [-90, 90]."
            )
        if not 0.0 <= self.strength <= 1000.0:
            raise ConfigError(
                f"`--key-light` strength is {self.strength}; pass a multiple of the photo's own "
                f"light in [0, 1000] (default {KEY_STRENGTH})."
            )
        if not 0.0 < self.size_deg <= 90.0:
            raise ConfigError(
                f"`--key-light` size is {self.size_deg}; pass the disc's angular diameter in (0, 90] "
                f"degrees (default {KEY_SIZE_DEG})."
            )

    @property
    def direction(self) -> np.ndarray:
        """`[3]` unit direction towards the light (Blender world, z up)."""
        return sun_direction(self.elevation_deg, self.azimuth_deg)

    def describe(self, angle_format: str = "g") -> str:
        """ "at azimuth A, elevation E, strength S, D degrees": the output line's words for it
        (`angle_format` formats the two angles: the CLI prints them to 0.1 degree)."""
        return (
            f"at azimuth {self.azimuth_deg:{angle_format}}, elevation "
            f"{self.elevation_deg:{angle_format}}, strength {self.strength:g}, "
            f"{self.size_deg:g} degrees"
        )


@dataclass(frozen=True, kw_only=True)
class DominantLight:
    """The light the cast shadow comes from.

    Attributes:
        direction_world: `[3]` unit direction towards it (Blender world, z up).
        share: the fraction of the ground's irradiance (upward-facing, from the upper hemisphere) it
            gives, in [0, 1]: the cast shadow darkens the ground by this much at most.
        size_deg: its angular diameter, degrees (the shadow's penumbra grows with it).
        source: what it is, for messages ("the key light", "the map's brightest region").
    """

    direction_world: np.ndarray
    share: float
    size_deg: float
    source: str


@dataclass(frozen=True, kw_only=True)
class InsertLighting:
    """The lighting an object is inserted under.

    Attributes:
        envmap: Blender-convention world map (what `--save-envmap` writes).
        camera: the background camera; the map is turned into its frame for the model.
        key_light: the key light added to a map built from the photo, or None.
        source: what the map is, for messages.
    """

    envmap: EnvironmentMap
    camera: BackgroundCamera
    key_light: KeyLight | None = None
    source: str = ""


@dataclass(frozen=True, kw_only=True)
class ObjectExtent:
    """The object's bounding box in its photo (alpha > 0.5), pixel edges: rows `top..bottom`, columns
    `left..right` (exclusive ends)."""

    top: int
    bottom: int
    left: int
    right: int

    @property
    def height(self) -> int:
        """Rows the object spans."""
        return self.bottom - self.top

    @property
    def width(self) -> int:
        """Columns the object spans."""
        return self.right - self.left

    @property
    def foot_xy(self) -> tuple[float, float]:
        """Its lowest centre point `(x, y)` in pixel-edge coordinates: the bottom edge of its box."""
        return (self.left + self.right) / 2.0, float(self.bottom)


@dataclass(frozen=True, kw_only=True)
class Placement:
    """Where the object goes in the background.

    Attributes:
        foot_xy: `(X, Y)` background pixel (column, row from the top-left, 0-based) of the object's
            lowest centre point: its lowest row of pixels lands on row Y, centred on column X.
        height_px: the object's height in background pixels.
        chosen: what was defaulted, for messages ("" when both were given).
    """

    foot_xy: tuple[float, float]
    height_px: float
    chosen: str = ""

    @property
    def foot_edge(self) -> tuple[float, float]:
        """The foot in pixel-edge coordinates: `(X + 0.5, Y + 1)`."""
        return self.foot_xy[0] + 0.5, self.foot_xy[1] + 1.0


@dataclass(frozen=True, kw_only=True)
class PlacedObject:
    """The relit object scaled and moved into the background.

    Attributes:
        box: `(top, left, bottom, right)` background pixels it may cover.
        rgb: `[bottom - top, right - left, 3]` float32 sRGB in [0, 1] (not premultiplied).
        alpha: `[bottom - top, right - left]` float32 coverage in [0, 1]; 0 outside the object.
        foot_edge: its lowest centre point in background pixel-edge coordinates.
        height_px: its height in background pixels.
    """

    box: tuple[int, int, int, int]
    rgb: np.ndarray
    alpha: np.ndarray
    foot_edge: tuple[float, float]
    height_px: float

    def full_alpha(self, height: int, width: int) -> np.ndarray:
        """`[height, width]` float32 coverage over the whole background."""
        out = np.zeros((height, width), np.float32)
        t, l, b, r = self.box
        out[t:b, l:r] = self.alpha
        return out


# ----- lighting -----


def _triangle(s: np.ndarray) -> np.ndarray:
    """Fold a coordinate into [-1, 1] by mirroring at +-1 (period 4).

    Example:
        >>> _triangle(np.array([0.0, 0.5, 1.0, 1.25, 2.0, -1.25, -2.0])).tolist()
        [0.0, 0.5, 1.0, 0.75, 0.0, -0.75, 0.0]
    """
    return 1.0 - np.abs(np.mod(s + 1.0, 4.0) - 2.0)


def _blur(x: np.ndarray, radius: int, passes: int = 3) -> np.ndarray:
    """About Gaussian (sigma ~ radius): `passes` box means (`detail_transfer.box_mean`, cut at the
    borders, so the support is finite: nothing leaks farther than `passes * radius`)."""
    for _ in range(passes if radius > 0 else 0):
        x = dt.box_mean(x, radius)
    return x


def _sample(image: np.ndarray, px: np.ndarray, py: np.ndarray) -> np.ndarray:
    """Bilinear samples of `[h, w, C]` at normalised coordinates px, py in [0, 1] (edges), clamped."""
    src = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1), np.float32))[None]
    grid = torch.from_numpy(np.stack([px * 2 - 1, py * 2 - 1], -1).astype(np.float32))[None]
    out = F.grid_sample(src, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out[0].permute(1, 2, 0).numpy()


def _resize(image: np.ndarray, height: int, width: int) -> np.ndarray:
    """`[h, w, C]` resized with antialiasing."""
    src = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1), np.float32))[None]
    out = F.interpolate(src, size=(height, width), mode="bilinear", antialias=True)
    return out[0].permute(1, 2, 0).numpy()


def inverse_tone(rgb_linear: np.ndarray, peak: float = INVERSE_TONE_PEAK) -> np.ndarray:
    """Expand display-referred linear values in [0, 1] to HDR: `c / max(1 - c, 1 / peak)`.

    Example:
        >>> inverse_tone(np.array([0.0, 0.5, 1.0])).tolist()
        [0.0, 1.0, 8.0]
    """
    c = np.clip(np.asarray(rgb_linear, np.float64), 0.0, 1.0)
    return (c / np.maximum(1.0 - c, 1.0 / peak)).astype(np.float32)


def light_from_photo(
    rgb_srgb: Float[np.ndarray, "H W 3"],
    camera: BackgroundCamera,
    key_light: KeyLight | None = None,
    *,
    width: int = LIGHT_FROM_PHOTO_WIDTH,
) -> EnvironmentMap:
    """An HDR environment map guessed from a background photo, plus an optional key light.

    The photo covers the part of the sphere its camera sees (a pinhole of `camera.fov_deg`); around it
    the sphere is filled by the photo mirrored at its edges, stretched so that the two sides meet
    behind the camera at the photo's middle column, and blurred (a photo says little about what is
    behind the camera); towards the poles it fades to the mean of the photo's top or bottom rows. The
    sRGB values are linearised and expanded by `inverse_tone`. A `key_light` is added as a disc whose
    irradiance is `strength` times pi times the map's mean radiance (`gaffer_envmap.studio.add_disc_light`).

    The key light is mostly outside the frame (the sun, a window, a lamp behind the camera): the wrap
    alone gets the dominant light's direction wrong by about 50 degrees (median over 8 bundled
    HDRIs x 4 views, 60-degree 8-bit crops), so pass it.

    Args:
        rgb_srgb: the background photo, sRGB in [0, 1].
        camera: its camera.
        key_light: the key light, or None.
        width: the map's width (height `width // 2`).

    Returns:
        A Blender-convention map `[width // 2, width, 3]`.

    Example:
        >>> rgb = np.full((30, 40, 3), 0.5, np.float32)
        >>> env = light_from_photo(rgb, BackgroundCamera(width=40, height=30), width=32)
        >>> env.radiance_linear.shape, round(float(env.radiance_linear.mean()), 3)
        ((16, 32, 3), 0.272)
    """
    img = np.clip(np.asarray(rgb_srgb, np.float32), 0.0, 1.0)
    h_img, w_img = img.shape[:2]
    he, we = width // 2, width
    d_world = direction_grid(he, we)  # [He, We, 3]
    d_cam = d_world @ np.asarray(camera.w2c.rotation, np.float64).T  # Blender camera: x, y, -z fwd
    x, y, z = d_cam[..., 0], d_cam[..., 1], -d_cam[..., 2]
    half_h = math.radians(camera.fov_deg) / 2.0
    tan_v = math.tan(half_h) * h_img / w_img
    half_v = math.atan(tan_v)
    # angular coordinates about the view: s, t = +-1 on the frame's edges
    phi = np.arctan2(x, z)
    theta = np.arcsin(np.clip(y, -1.0, 1.0))
    s = np.where(
        np.abs(phi) <= half_h,
        phi / half_h,
        np.sign(phi) * (1.0 + (np.abs(phi) - half_h) / (math.pi - half_h)),
    )  # +-2 behind the camera: both sides fold to the middle column there
    t = np.where(
        np.abs(theta) <= half_v,
        theta / half_v,
        np.sign(theta) * (1.0 + (np.abs(theta) - half_v) / (math.pi / 2 - half_v)),
    )
    small_w = 32
    small_h = max(round(small_w * h_img / w_img), 2)
    small = _blur(_resize(img, small_h, small_w), 2)
    ext = _sample(small, (_triangle(s) + 1) / 2, (1 - _triangle(t)) / 2)
    band = max(small_h // 4, 1)
    pole_top, pole_bottom = small[:band].mean((0, 1)), small[-band:].mean((0, 1))
    over = np.clip((np.abs(theta) - half_v) / (math.pi / 2 - half_v), 0.0, 1.0)[..., None] ** 2
    pole = np.where(theta[..., None] > 0, pole_top, pole_bottom)
    ext = (1 - over) * ext + over * pole
    # inside the frame: the photo itself (perspective), at about the map's resolution
    inside = (z > 1e-6) & (np.abs(x) <= np.tan(half_h) * z) & (np.abs(y) <= tan_v * z)
    sharp_w = max(16, round(we * camera.fov_deg / 360.0 * 2))
    sharp = _resize(img, max(round(sharp_w * h_img / w_img), 2), sharp_w)
    zs = np.where(inside, z, 1.0)
    px = (x / zs / math.tan(half_h) + 1) / 2
    py = (1 - y / zs / tan_v) / 2
    photo = _sample(sharp, px, py)
    edge = np.minimum(1 - np.abs(2 * px - 1), 1 - np.abs(2 * py - 1))  # 0 on the frame's border
    w_in = (inside * np.clip(edge / 0.1, 0.0, 1.0))[..., None]
    rgb = w_in * photo + (1 - w_in) * ext
    env = EnvironmentMap(radiance_linear=inverse_tone(dt.srgb_to_linear(rgb)))
    if key_light is None or key_light.strength == 0:
        return env
    omega = row_solid_angle(he, we)
    mean = np.einsum("hwc,h->c", env.radiance_linear.astype(np.float64), omega) / (4 * math.pi)
    irradiance = key_light.strength * math.pi * float(mean @ np.array([0.2126, 0.7152, 0.0722]))
    return add_disc_light(
        env, key_light.direction, key_light.size_deg / 2.0, np.full(3, max(irradiance, 1e-6))
    )


def dominant_light(env: EnvironmentMap, key_light: KeyLight | None = None) -> DominantLight:
    """The light the cast shadow comes from, and its share of the ground's irradiance.

    With a `key_light` (added to a map built from a photo), that light, exactly: its share is its
    irradiance on the ground over the map's. Otherwise the brightest 20-degree cone of the upper
    hemisphere, weighted as the ground sees it (radiance x solid angle x cos): its power-weighted mean
    direction, its share of the ground's irradiance, and twice its angular spread as its size.

    Example:
        >>> env = EnvironmentMap(radiance_linear=np.full((16, 32, 3), 0.1, np.float32))
        >>> lit = add_disc_light(env, np.array([0.0, 0.6, 0.8]), 3.0, (3.0, 3.0, 3.0))
        >>> light = dominant_light(lit)
        >>> np.round(light.direction_world, 1) + 0.0, round(light.share, 2)
        (array([0. , 0.6, 0.8]), 0.89)
    """
    lum = np.array([0.2126, 0.7152, 0.0722])
    small = env if env.height <= 32 else resize_conservative(env, 32)
    he, we = small.height, small.width
    dirs = direction_grid(he, we, small.convention, small.alignment).reshape(-1, 3)
    omega = np.repeat(row_solid_angle(he, we, small.alignment)[:, None], we, 1).reshape(-1)
    y = small.radiance_linear.reshape(-1, 3).astype(np.float64) @ lum
    ground = y * omega * np.clip(dirs[:, 2], 0.0, None)  # irradiance of an upward-facing ground
    total = float(ground.sum())
    if key_light is not None:
        d = key_light.direction
        radius = math.radians(key_light.size_deg / 2.0)
        e_key = _disc_ground_irradiance(env, d, radius)
        share = e_key / total if total > 0 else 0.0
        return DominantLight(
            direction_world=d,
            share=float(np.clip(share, 0.0, 1.0)),
            size_deg=key_light.size_deg,
            source=f"the key light (azimuth {key_light.azimuth_deg:.1f}, elevation "
            f"{key_light.elevation_deg:.1f})",
        )
    up = dirs[:, 2] > math.sin(math.radians(1.0))
    cand = dirs[up]
    cone = (cand @ dirs.T) > math.cos(math.radians(20.0))  # [candidates, all]
    sums = cone @ ground
    if total <= 0 or not np.isfinite(total) or len(cand) == 0:
        return DominantLight(
            direction_world=np.array([0.0, 0.0, 1.0]), share=0.0, size_deg=90.0, source="none"
        )
    best = int(np.argmax(sums))
    w = ground * cone[best]
    mean_dir = (w[:, None] * dirs).sum(0)
    mean_dir /= np.linalg.norm(mean_dir)
    ang = np.arccos(np.clip(dirs @ mean_dir, -1.0, 1.0))
    spread = math.degrees(math.sqrt(float((w * ang**2).sum() / w.sum())))
    return DominantLight(
        direction_world=mean_dir,
        share=float(np.clip(sums[best] / total, 0.0, 1.0)),
        size_deg=float(np.clip(2.0 * spread, 0.5, 40.0)),
        source="the map's brightest region",
    )


def _disc_ground_irradiance(env: EnvironmentMap, direction: np.ndarray, radius: float) -> float:
    """Ground irradiance (luminance) from the map's pixels within `radius` (plus half a pixel) of
    `direction`: the key light's part of the ground's light."""
    lum = np.array([0.2126, 0.7152, 0.0722])
    dirs = direction_grid(env.height, env.width, env.convention, env.alignment)
    omega = row_solid_angle(env.height, env.width, env.alignment)[:, None]
    pix = math.pi / env.height
    near = (dirs @ direction) > math.cos(radius + pix)
    y = env.radiance_linear.astype(np.float64) @ lum
    ground = y * omega * np.clip(dirs[..., 2], 0.0, None)
    return float(ground[near].sum())


# ----- placement -----


def object_extent(alpha: Float[np.ndarray, "H W"]) -> ObjectExtent:
    """The bounding box of `alpha > 0.5` (the object) in its photo.

    Raises:
        InputValueError: when no pixel is above 0.5.

    Example:
        >>> a = np.zeros((10, 8), np.float32); a[2:7, 3:5] = 1
        >>> e = object_extent(a); (e.height, e.width, e.foot_xy)
        (5, 2, (4.0, 7.0))
    """
    ys, xs = np.nonzero(np.asarray(alpha) > ALPHA_THRESHOLD)
    if len(ys) == 0:
        raise InputValueError("The object mask marks no pixel (no value above 0.5).")
    return ObjectExtent(
        top=int(ys.min()), bottom=int(ys.max()) + 1, left=int(xs.min()), right=int(xs.max()) + 1
    )


def default_placement(width: int, height: int, object_height_px: float | int) -> Placement:
    """The object's lowest centre point at the centre of the background's bottom third
    (`DEFAULT_FOOT`), at its height in its own photo."""
    x = min(int(width * DEFAULT_FOOT[0]), width - 1)
    y = min(int(height * DEFAULT_FOOT[1]), height - 1)
    return Placement(foot_xy=(float(x), float(y)), height_px=float(object_height_px))


def resolve_placement(
    background_wh: tuple[int, int],
    extent: ObjectExtent,
    *,
    at_xy: tuple[float | int, float | int] | None = None,
    height_px: float | int | None = None,
) -> Placement:
    """The placement of `--at` and `--height`, defaults filled in, checked against the background.

    Args:
        background_wh: `(width, height)` of the background.
        extent: the object's box in its photo (`object_extent`).
        at_xy: `(X, Y)`: the pixel its lowest centre point lands on, or None for `DEFAULT_FOOT`.
        height_px: its height in background pixels, or None for its height in its photo.

    Raises:
        InputValueError: `--at` outside the background, or a height below `MIN_HEIGHT_PX` or one that
            does not fit (the object would leave the frame); the message names the flag and the most
            that fits.
    """
    w, h = background_wh
    chosen: list[str] = []
    if at_xy is None:
        d = default_placement(w, h, extent.height)
        at_xy = d.foot_xy
        chosen.append(
            f"--at {at_xy[0]:g},{at_xy[1]:g} (default: the centre of the bottom third of the frame)"
        )
    x, y = (float(v) for v in at_xy)
    if not (math.isfinite(x) and math.isfinite(y) and 0 <= x < w and 0 <= y < h):
        raise InputValueError(
            f"`--at` {x:g},{y:g} is outside the background ({w}x{h}): pass X in [0, {w - 1}] and "
            f"Y in [0, {h - 1}], pixels from the top-left (where the object's lowest point lands)."
        )
    if height_px is None:
        height_px = float(extent.height)
        chosen.append(f"--height {height_px:g} (default: as in the object photo)")
    placement = Placement(foot_xy=(x, y), height_px=float(height_px), chosen="; ".join(chosen))
    fx, fy = placement.foot_edge
    half_w_per_px = extent.width / 2.0 / extent.height  # half the width per pixel of height
    fits = min(fy, min(fx, w - fx) / half_w_per_px)  # the top edge, then the sides
    if not (math.isfinite(placement.height_px) and placement.height_px >= MIN_HEIGHT_PX):
        raise InputValueError(
            f"`--height` is {placement.height_px:g}; pass the object's height in background pixels, "
            f"at least {MIN_HEIGHT_PX:g} (at most {math.floor(fits)} fits at `--at` {x:g},{y:g})."
        )
    if placement.height_px > fits + 1e-6:
        where = "above the top" if fy <= min(fx, w - fx) / half_w_per_px else "past a side"
        given = (
            "" if "--height" not in placement.chosen else " (its height in its photo, the default)"
        )
        raise InputValueError(
            f"`--height` {placement.height_px:g}{given} does not fit: at `--at` {x:g},{y:g} the object "
            f"({extent.width}x{extent.height} px in its photo) would reach {where} of the "
            f"{w}x{h} background; pass `--height` {math.floor(fits)} or less, or move it with "
            "`--at`."
        )
    return placement


def place_object(
    relit: RelitObject, extent: ObjectExtent, placement: Placement, background_hw: tuple[int, int]
) -> PlacedObject:
    """Scale and move the relit object so its lowest centre point lands on `placement.foot_xy`.

    The box is resampled premultiplied (bilinear, antialiased when shrinking), so no colour bleeds in
    from outside the mask; coverage outside the object stays exactly 0.
    """
    h_bg, w_bg = background_hw
    s = placement.height_px / extent.height  # background pixels per photo pixel
    (ox, oy), (fx, fy) = extent.foot_xy, placement.foot_edge
    t, l, b, r = relit.box
    a = np.asarray(relit.alpha, np.float32)
    premul = np.concatenate([relit.rgb * a[..., None], a[..., None]], axis=-1)  # [hb, wb, 4]
    hb, wb = a.shape
    if s < 1.0:  # shrink with antialiasing first; then only a sub-pixel shift is left
        nh, nw = max(round(hb * s), 1), max(round(wb * s), 1)
        premul = _resize(premul, nh, nw)
    else:
        nh, nw = hb, wb
    ky, kx = nh / hb, nw / wb
    # the background pixels the box can reach
    top = max(math.floor(fy + s * (t - oy)), 0)
    bottom = min(math.ceil(fy + s * (b - oy)), h_bg)
    left = max(math.floor(fx + s * (l - ox)), 0)
    right = min(math.ceil(fx + s * (r - ox)), w_bg)
    if bottom <= top or right <= left:
        raise InputValueError("The placed object covers no pixel of the background.")
    qy = np.arange(top, bottom) + 0.5
    qx = np.arange(left, right) + 0.5
    # background pixel centre -> photo edge coordinate -> resized box edge coordinate -> [0, 1]
    py = ((oy + (qy - fy) / s) - t) * ky / nh
    px = ((ox + (qx - fx) / s) - l) * kx / nw
    src = torch.from_numpy(np.ascontiguousarray(premul.transpose(2, 0, 1)))[None]
    grid = np.stack(np.broadcast_arrays(px[None, :] * 2 - 1, py[:, None] * 2 - 1), -1)
    out = (
        F.grid_sample(
            src,
            torch.from_numpy(grid.astype(np.float32))[None],
            mode="bilinear",
            padding_mode="zeros",
            align_corners=False,
        )[0]
        .permute(1, 2, 0)
        .numpy()
    )
    alpha = np.clip(out[..., 3], 0.0, 1.0)
    alpha[alpha < 1.0 / 512.0] = 0.0  # below a quarter of an 8-bit step: not covered
    rgb = np.where(alpha[..., None] > 0, out[..., :3] / np.maximum(alpha, 1e-6)[..., None], 0.0)
    return PlacedObject(
        box=(top, left, bottom, right),
        rgb=np.clip(rgb, 0.0, 1.0).astype(np.float32),
        alpha=alpha.astype(np.float32),
        foot_edge=(fx, fy),
        height_px=placement.height_px,
    )


# ----- shadow -----


def _shadow_offsets(
    light: DominantLight, camera: BackgroundCamera, foot_y: float
) -> tuple[float, float, float] | None:
    """Image offset `(dx, dy)` of a point's shadow per pixel of its height above the ground, and the
    ground's foreshortening k at the foot; None when the light is too low to cast a shadow."""
    right, forward = camera.ground_axes()
    d = np.asarray(light.direction_world, np.float64)
    lx, ly, lz = float(d @ right), float(d @ forward), float(d[2])
    if lz < math.sin(math.radians(MIN_SHADOW_ELEVATION_DEG)):
        return None
    horiz = math.hypot(lx, ly)
    k = max((foot_y - camera.horizon_row) / camera.focal_px, MIN_FORESHORTENING)
    if horiz < 1e-9:  # overhead: the shadow is right under the object
        return 0.0, 0.0, k
    length = min(horiz / lz, MAX_SHADOW_LENGTH)  # ground length per unit of height
    # the shadow falls away from the light; a step away from the camera moves up in the image
    return -lx / horiz * length, ly / horiz * length * k, k


def _draw_ellipse(
    canvas: np.ndarray, cx: float, cy: float, sx: float, sy: float, value: float
) -> None:
    """Max a filled, anti-aliased axis-aligned ellipse (centre and semi-axes in the canvas's pixel-edge
    coordinates) of `value` into `canvas`, in place."""
    h, w = canvas.shape
    y0, y1 = max(math.floor(cy - sy - 1), 0), min(math.ceil(cy + sy + 1), h)
    x0, x1 = max(math.floor(cx - sx - 1), 0), min(math.ceil(cx + sx + 1), w)
    if y1 <= y0 or x1 <= x0:
        return
    gy = (np.arange(y0, y1) + 0.5 - cy)[:, None] / sy
    gx = (np.arange(x0, x1) + 0.5 - cx)[None, :] / sx
    r = np.sqrt(gx**2 + gy**2)
    cover = np.clip(0.5 + (1.0 - r) * min(sx, sy), 0.0, 1.0) * value  # about 1 px of edge
    np.maximum(canvas[y0:y1, x0:x1], cover.astype(np.float32), out=canvas[y0:y1, x0:x1])


@dataclass(frozen=True, kw_only=True)
class _Rows:
    """Per row of the placed object's box: its height above the foot (pixel centres), whether it
    covers anything, its centre column, half-width and most opaque coverage (background pixels)."""

    height: np.ndarray
    covered: np.ndarray
    centre: np.ndarray
    half: np.ndarray
    cover: np.ndarray


def _rows(placed: PlacedObject) -> _Rows:
    t, l, _, _ = placed.box
    a = placed.alpha
    solid = a > ALPHA_THRESHOLD
    first = np.argmax(solid, axis=1)
    last = a.shape[1] - 1 - np.argmax(solid[:, ::-1], axis=1)
    return _Rows(
        height=placed.foot_edge[1] - (t + np.arange(a.shape[0]) + 0.5),
        covered=solid.any(1),
        centre=l + (first + last + 1) / 2.0,
        half=(last + 1 - first) / 2.0,
        cover=a.max(1),
    )


class _WorkGrid:
    """A coarse grid over a background region `(top, left, bottom, right)`: one work pixel is `f`
    background pixels, so that the shadow's cost does not grow with the picture (it is soft anyway)."""

    def __init__(self, region: tuple[int, int, int, int], f: float) -> None:
        self.region, self.f = region, f
        y0, x0, y1, x1 = region
        self.canvas = np.zeros(
            (max(math.ceil((y1 - y0) / f), 1), max(math.ceil((x1 - x0) / f), 1)), np.float32
        )

    def ellipse(self, cx: float, cy: float, sx: float, sy: float, value: float) -> None:
        """Max an ellipse given in background pixel-edge coordinates into a fresh layer."""
        y0, x0 = self.region[0], self.region[1]
        _draw_ellipse(
            self.canvas,
            (cx - x0) / self.f,
            (cy - y0) / self.f,
            max(sx / self.f, 0.5),
            max(sy / self.f, 0.5),
            value,
        )

    def soften(self, sigma_bg: float) -> np.ndarray:
        """The canvas blurred by about `sigma_bg` background pixels; the canvas is cleared."""
        out = np.clip(_blur(self.canvas, max(round(sigma_bg / self.f), 1)), 0.0, 1.0)
        self.canvas = np.zeros_like(self.canvas)
        return out

    def to_region(self, work: np.ndarray) -> np.ndarray:
        """A work map sampled at the region's pixel centres (bilinear), `[bottom - top, right - left]`."""
        y0, x0, y1, x1 = self.region
        hw, ww = work.shape
        gy = 2.0 * ((np.arange(y1 - y0) + 0.5) / self.f) / hw - 1.0
        gx = 2.0 * ((np.arange(x1 - x0) + 0.5) / self.f) / ww - 1.0
        grid = np.stack(np.broadcast_arrays(gx[None, :], gy[:, None]), -1).astype(np.float32)
        out = F.grid_sample(
            torch.from_numpy(np.ascontiguousarray(work))[None, None],
            torch.from_numpy(grid)[None],
            mode="bilinear",
            padding_mode="border",
            align_corners=False,
        )
        return out[0, 0].numpy()


SHADOW_WORK_HEIGHT = 192.0
"""The shadow is drawn on a grid where the object is at most this many pixels tall (`_WorkGrid`)."""


def _cast(
    placed: PlacedObject,
    rows: _Rows,
    offsets: tuple[float, float, float],
    light: DominantLight,
    camera: BackgroundCamera,
    bands: int,
) -> tuple[tuple[int, int, int, int], np.ndarray] | None:
    """The cast shadow's occlusion over a region of the background, or None when nothing casts."""
    dx, dy, k = offsets
    fy = placed.foot_edge[1]
    up = rows.covered & (rows.height > 0)
    if not up.any():
        return None
    t = placed.box[0]
    f = max(1.0, placed.height_px / SHADOW_WORK_HEIGHT)
    # samples along the height, close enough that consecutive ellipses overlap by half, at most
    # one work pixel apart (more samples than rows where the shadow is long)
    step = math.hypot(dx, dy)
    smallest = max(float(np.median(rows.half[up])) * min(k, 1.0) / f, 0.5)  # work pixels
    spacing = float(np.clip(0.5 * smallest / max(step, 1e-6), 1.0 / 16.0, 1.0)) * f
    h_lo, h_hi = float(rows.height[up].min()), float(rows.height[up].max())
    hq = np.arange(h_lo, h_hi + spacing / 2, spacing)
    r = np.clip(np.round(fy - hq - t - 0.5).astype(np.int64), 0, len(rows.height) - 1)
    keep = up[r]
    hq, r = hq[keep], r[keep]
    cx, cy = rows.centre[r] + hq * dx, fy + hq * dy
    sx, sy = rows.half[r], np.maximum(rows.half[r] * k, 0.5)
    sin_e = max(float(light.direction_world[2]), 0.05)
    grow = 0.5 * math.radians(light.size_deg) / sin_e * (1.0 + k) / 2.0  # sigma per px of height
    pad = int(3 * (f + grow * h_hi) + sx.max() + 2 * f + 4)
    b, l, rr = placed.box[2], placed.box[1], placed.box[3]
    region = (
        max(int(min(cy.min(), t)) - pad, 0),
        max(int(min(cx.min(), l)) - pad, 0),
        min(int(max(cy.max(), b)) + pad, camera.height),
        min(int(max(cx.max(), rr)) + pad, camera.width),
    )
    if region[2] <= region[0] or region[3] <= region[1]:
        return None
    grid = _WorkGrid(region, f)
    occluded = np.zeros_like(grid.canvas)
    for lo, hi in itertools.pairwise(np.linspace(0.0, h_hi + 1e-6, bands + 1)):
        sel = np.nonzero((hq >= lo) & (hq < hi))[0]
        for i in sel:
            grid.ellipse(
                float(cx[i]), float(cy[i]), float(sx[i]), float(sy[i]), float(rows.cover[r[i]])
            )
        if len(sel):
            occluded = 1.0 - (1.0 - occluded) * (1.0 - grid.soften(0.5 + grow * (lo + hi) / 2.0))
    out = grid.to_region(occluded)
    horizon = math.ceil(camera.horizon_row) - region[0]
    if horizon > 0:
        out[: min(horizon, out.shape[0])] = 0.0  # no ground above the horizon
    return region, out


def cast_shadow_2d(
    placed: PlacedObject,
    camera: BackgroundCamera,
    light: DominantLight,
    *,
    bands: int = 4,
) -> Float[np.ndarray, "H W"]:
    """The factor `[H, W]` the background is multiplied by (linear light) under a pixel-height shadow.

    Each row of the object is taken as a horizontal slice of a solid of revolution: a disc as wide as
    the row, standing `h` pixels above the ground line through the object's lowest point (its pixel
    height). A directional light throws that disc onto the ground unchanged, moved by `h` times the
    light's ground offset per unit of height; seen by the camera it is an ellipse, the ground being
    foreshortened at the foot's row by `k = (foot row - horizon row) / focal length`. The cast shadow
    is the union of these ellipses (sampled along the height so that they overlap), softened by a
    penumbra that grows with the height and the light's size (contact hardening, in `bands` height
    bands), and clipped at the horizon; it is drawn on a grid where the object is at most
    `SHADOW_WORK_HEIGHT` pixels tall and resampled. It removes up to `light.share` of the light; a
    contact shadow under the foot removes up to `CONTACT_STRENGTH` of the rest.

    Returns:
        float32 in (0, 1]; exactly 1 where the shadow darkens by less than `SHADOW_CUTOFF`.
    """
    h_bg, w_bg = camera.height, camera.width
    fx, fy = placed.foot_edge
    rows = _rows(placed)
    if not rows.covered.any():
        return np.ones((h_bg, w_bg), np.float32)
    offsets = _shadow_offsets(light, camera, fy)
    k = max((fy - camera.horizon_row) / camera.focal_px, MIN_FORESHORTENING)
    lit = np.ones((h_bg, w_bg), np.float32)  # the share of the dominant light that still arrives
    cast = (
        None
        if offsets is None or light.share <= 0
        else _cast(placed, rows, offsets, light, camera, bands)
    )
    if cast is not None:
        (y0, x0, y1, x1), occluded = cast
        lit[y0:y1, x0:x1] = 1.0 - occluded
    # contact shadow: the sky the object hides from the ground just under its foot
    low = rows.covered & (rows.height <= max(0.1 * placed.height_px, 1.0))
    semi = float(rows.half[low].max() if low.any() else rows.half[rows.covered].max()) * 1.1
    ry = max(k * semi, 1.0)
    f = max(1.0, placed.height_px / SHADOW_WORK_HEIGHT)
    pad = int(3 * ry + 2 * f + 4)
    region = (
        max(int(fy - ry) - pad, 0),
        max(int(fx - semi) - pad, 0),
        min(int(fy + ry) + pad, h_bg),
        min(int(fx + semi) + pad, w_bg),
    )
    contact = np.zeros((h_bg, w_bg), np.float32)
    if region[2] > region[0] and region[3] > region[1]:
        grid = _WorkGrid(region, f)
        grid.ellipse(fx, fy, semi, ry, 1.0)
        y0, x0, y1, x1 = region
        contact[y0:y1, x0:x1] = grid.to_region(grid.soften(0.5 * ry))
    factor = light.share * lit + (1.0 - light.share) * (1.0 - CONTACT_STRENGTH * contact)
    factor = np.clip(factor, 0.0, 1.0).astype(np.float32)
    factor[factor > 1.0 - SHADOW_CUTOFF] = 1.0
    return factor


# ----- composite and the whole insertion -----


def composite(
    background: Photo, placed: PlacedObject, shadow: Float[np.ndarray, "H W"] | None = None
) -> np.ndarray:
    """The background with `shadow` multiplied in (linear light) and the object over it (sRGB,
    straight alpha, as `photo.paste_back` composites).

    Returns:
        `[H, W, 3]` uint8; every pixel the object does not cover and the shadow does not darken holds
        the background's bytes (the background's alpha, if any, is dropped).
    """
    base = np.array(background.rgb, np.float32, copy=True)
    h, w = base.shape[:2]
    touched = np.zeros((h, w), bool) if shadow is None else shadow < 1.0
    if shadow is not None and touched.any():
        lin = dt.srgb_to_linear(base[touched]) * shadow[touched][:, None]
        base[touched] = dt.linear_to_srgb(lin)
    t, l, b, r = placed.box
    a = placed.alpha[..., None]
    base[t:b, l:r] = a * placed.rgb + (1.0 - a) * base[t:b, l:r]
    out = quantize(base)
    keep = ~touched & (placed.full_alpha(h, w) <= 0.0)
    out[keep] = background.rgb_u8[keep]  # away from the object and its shadow: the bytes as read
    return out
