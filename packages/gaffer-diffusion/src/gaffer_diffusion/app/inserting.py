"""The app's "Insert into a photo" tab without Gradio: settings, clicks and previews.

The insertion itself is `Engine.insert`, which calls what `gaffer-diffusion insert` calls
(`gaffer_diffusion.insert`: `light_from_photo`, `resolve_placement`, `insert_object`). This module
turns the page's clicks into the command's arguments and draws what the page shows:

- a click on the placement preview (the background, shrunk to `PLACE_PREVIEW_SIDE` at most) is the
  background pixel `--at X,Y` (`click_to_at`);
- a click on the key-light preview (the lighting as a lat-long panorama, `KEY_PREVIEW_WH`, rolled so
  that its middle column is straight ahead of the camera) is the key light's azimuth and elevation in
  `--key-light AZ,EL`'s convention, degrees clockwise from world +y seen from above
  (`key_light_from_click`; `key_light_pixel` is its inverse, for the marker).
"""

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from PIL import Image

from gaffer_diffusion._choices import BACKDROP_FOV_DEG
from gaffer_diffusion.errors import InputValueError
from gaffer_diffusion.insert_geometry import KEY_SIZE_DEG, KeyLight, Placement
from gaffer_envmap.conventions import direction_to_uv, uv_to_direction
from gaffer_envmap.environment_map import EnvironmentMap

__all__ = [
    "INSERT_SHADOWS",
    "KEY_PREVIEW_WH",
    "PLACE_PREVIEW_SIDE",
    "InsertOutcome",
    "InsertSettings",
    "InsertShadow",
    "click_to_at",
    "key_light_from_click",
    "key_light_of",
    "key_light_pixel",
    "lighting_panorama",
    "placement_preview",
    "preview_size",
]

InsertShadow = Literal["2d", "none"]
"""The app's shadow choices: `insert --shadow 2d` (the pixel-height shadow) or `none` (Blender's
`cycles` shadow needs bpy in the server's environment)."""

INSERT_SHADOWS: tuple[InsertShadow, ...] = ("2d", "none")

PLACE_PREVIEW_SIDE = 768
"""Longest side of the placement preview; a larger background is shown shrunk (`click_to_at` scales)."""

KEY_PREVIEW_WH = (512, 256)
"""Width and height of the key-light preview: the 256 x 128 lighting map, each pixel shown 2 x 2."""

_MARKER = (255, 40, 200)
"""The markers' colour (magenta: rare in photos and skies), drawn with a dark outline."""


@dataclass(frozen=True, kw_only=True)
class InsertSettings:
    """What the tab's controls say, as `gaffer-diffusion insert`'s flags.

    Attributes:
        at_xy: `--at X,Y`: the background pixel (column, row from the top-left) of the object's lowest
            centre point, or None for the centre of the bottom third.
        height_px: `--height`: the object's height in background pixels, or None for its height in
            its own photo.
        fov_deg: `--fov`: the background's horizontal field of view, degrees.
        key_light: `--key-light`: added to the map built from the background, or None (none given).
        shadow: `--shadow`: "2d" or "none".
        seed: `--seed`.
        num_inference_steps: `--steps`, or None for the model's suggestion.

    Raises:
        InputValueError: a shadow mode the app does not offer, a step count outside 1..1000.
    """

    at_xy: tuple[float | int, float | int] | None = None
    height_px: float | int | None = None
    fov_deg: float | int = BACKDROP_FOV_DEG
    key_light: KeyLight | None = None
    shadow: InsertShadow = "2d"
    seed: int = 0
    num_inference_steps: int | None = None

    def __post_init__(self) -> None:
        if self.shadow not in INSERT_SHADOWS:
            raise InputValueError(
                f"`shadow` is {self.shadow!r}; pass one of {', '.join(INSERT_SHADOWS)} (the app has "
                "no Blender shadow yet)."
            )
        steps = self.num_inference_steps
        if steps is not None and not 1 <= steps <= 1000:
            raise InputValueError(f"`steps` is {steps}; pass 1..1000, or leave it empty.")


@dataclass(frozen=True, kw_only=True)
class InsertOutcome:
    """An insertion, for the page.

    Attributes:
        image: `[H, W, 3]` uint8: the background at its full size with the object and its shadow.
        mask: `[h, w]` uint8 the object's mask in its own photo (the uploaded one, its alpha, or
            GrabCut's).
        placement: where it went (`--at`, `--height`, what was defaulted).
        lighting: what the lighting was, in words.
        shadow: what the shadow came from, in words.
        model: the model's label.
        steps: denoising steps used.
        seconds: time spent sampling, placing, shadowing and compositing.
    """

    image: np.ndarray
    mask: np.ndarray
    placement: Placement
    lighting: str
    shadow: str
    model: str
    steps: int
    seconds: float


def _preview_scale(background_wh: tuple[int, int]) -> float:
    """Preview pixels per background pixel (1 up to `PLACE_PREVIEW_SIDE`)."""
    return min(1.0, PLACE_PREVIEW_SIDE / max(background_wh))


def preview_size(background_wh: tuple[int, int]) -> tuple[int, int]:
    """`(width, height)` of the placement preview of a background."""
    k = _preview_scale(background_wh)
    return max(round(background_wh[0] * k), 1), max(round(background_wh[1] * k), 1)


def click_to_at(
    index: tuple[int, int] | list[int], preview_wh: tuple[int, int], background_wh: tuple[int, int]
) -> tuple[int, int]:
    """`--at X,Y` of a click on the placement preview: the background pixel under the clicked one.

    Args:
        index: the clicked pixel `(x, y)` of the preview (Gradio's `SelectData.index`).
        preview_wh: the preview's `(width, height)`.
        background_wh: the background's `(width, height)`.

    Example:
        >>> click_to_at((10, 20), (384, 256), (768, 512))
        (21, 41)
        >>> click_to_at((10, 20), (300, 200), (300, 200))
        (10, 20)
    """
    (x, y), (pw, ph), (bw, bh) = index, preview_wh, background_wh
    col = math.floor((float(x) + 0.5) * bw / pw)
    row = math.floor((float(y) + 0.5) * bh / ph)
    return min(max(col, 0), bw - 1), min(max(row, 0), bh - 1)


def key_light_from_click(
    index: tuple[int, int] | list[int], preview_wh: tuple[int, int] = KEY_PREVIEW_WH
) -> tuple[float, float]:
    """`(azimuth, elevation)` degrees of a click on the key-light preview, in `--key-light`'s
    convention (`KeyLight`: clockwise from world +y seen from above; 0 straight ahead of the level
    camera, behind the object; 90 from the right; +-180 from behind the camera).

    The preview is the Blender lat-long map (world +y at u = 0.25) rolled by a quarter turn, so that
    straight ahead is its middle column: the click's direction is `uv_to_direction(u - 0.25, v)`.

    Example:
        >>> key_light_from_click((256, 128))  # the middle: straight ahead, on the horizon
        (0.35, -0.35)
        >>> key_light_from_click((383, 42))  # right of the middle, up: a light from the right
        (89.65, 60.12)
    """
    x, y = index
    pw, ph = preview_wh
    u = ((float(x) + 0.5) / pw - 0.25) % 1.0
    v = min(max((float(y) + 0.5) / ph, 0.0), 1.0)
    d = uv_to_direction(np.array(u), np.array(v))
    azimuth = math.degrees(math.atan2(float(d[0]), float(d[1])))
    elevation = math.degrees(math.asin(float(np.clip(d[2], -1.0, 1.0))))
    return round(azimuth, 2), round(elevation, 2)


def key_light_pixel(
    azimuth_deg: float | int,
    elevation_deg: float | int,
    preview_wh: tuple[int, int] = KEY_PREVIEW_WH,
) -> tuple[float, float]:
    """Where a key light is on the key-light preview: `(x, y)` in pixel-edge coordinates (the inverse
    of `key_light_from_click`)."""
    key = KeyLight(azimuth_deg=azimuth_deg, elevation_deg=elevation_deg)
    u, v = direction_to_uv(key.direction)
    pw, ph = preview_wh
    return ((float(u) + 0.25) % 1.0) * pw, float(v) * ph


def _draw_cross(img: np.ndarray, x: float, y: float, arm: int) -> None:
    """A crosshair with a dark outline centred on pixel-edge point `(x, y)`, in place."""
    h, w = img.shape[:2]
    cx, cy = math.floor(x), math.floor(y)
    for colour, thick in (((0, 0, 0), 2), (_MARKER, 1)):
        lo, hi = -(thick - 1), thick
        r0, r1 = max(cy + lo, 0), min(cy + hi, h)
        c0, c1 = max(cx - arm, 0), min(cx + arm + 1, w)
        img[r0:r1, c0:c1] = colour
        r0, r1 = max(cy - arm, 0), min(cy + arm + 1, h)
        c0, c1 = max(cx + lo, 0), min(cx + hi, w)
        img[r0:r1, c0:c1] = colour


def lighting_panorama(env: EnvironmentMap, key_light: KeyLight | None = None) -> np.ndarray:
    """The key-light preview: `[256, 512, 3]` uint8, the map tone-mapped and rolled so that straight
    ahead of the camera is the middle (behind the camera at the left and right edges), with a marker
    on the key light.

    Raises:
        InputValueError: a map that is not in the Blender convention (the app reads only those).
    """
    from gaffer_envmap.preview import tonemap_preview
    from gaffer_envmap.resample import resize_conservative

    if env.convention != "blender":
        raise InputValueError(f"The map is in the {env.convention!r} convention, not 'blender'.")
    pw, ph = KEY_PREVIEW_WH
    small = env if env.height == ph // 2 else resize_conservative(env, ph // 2)
    # u' = u + 0.25: world +y (u = 0.25, straight ahead of the level camera) to the middle column
    rolled = np.roll(small.radiance_linear, small.width // 4, axis=1)
    img = np.repeat(np.repeat(tonemap_preview(rolled), 2, axis=0), 2, axis=1)
    if key_light is not None:
        x, y = key_light_pixel(key_light.azimuth_deg, key_light.elevation_deg)
        _draw_cross(img, x, y, 9)
    img[:, pw // 2] = (img[:, pw // 2].astype(np.uint16) // 2 + 64).astype(np.uint8)  # ahead
    return img


def placement_preview(
    background_rgb: np.ndarray,
    at_xy: tuple[float | int, float | int],
    height_px: float | int | None,
) -> np.ndarray:
    """The placement preview: the background (shrunk to `PLACE_PREVIEW_SIDE`) with a crosshair on the
    object's lowest centre point and, given a height, a bar as tall as the object will be.

    Args:
        background_rgb: `[H, W, 3]` uint8 the background.
        at_xy: `(X, Y)` the background pixel of the object's lowest centre point.
        height_px: the object's height in background pixels, or None.
    """
    h, w = background_rgb.shape[:2]
    pw, ph = preview_size((w, h))
    img = background_rgb
    if (pw, ph) != (w, h):
        img = np.asarray(Image.fromarray(img).resize((pw, ph), Image.Resampling.LANCZOS))
    img = np.array(img[..., :3], np.uint8, copy=True)
    k = pw / w
    x, y = (at_xy[0] + 0.5) * k, (at_xy[1] + 1.0) * k  # the foot's pixel-edge point
    if height_px is not None and height_px > 0:
        top = max(math.floor(y - height_px * k), 0)
        col = min(max(math.floor(x), 0), pw - 1)
        img[top : max(math.floor(y), top), max(col - 1, 0) : col + 2] = (0, 0, 0)
        img[top : max(math.floor(y), top), col] = _MARKER
    _draw_cross(img, x, y - 0.5, max(6, round(min(pw, ph) / 40)))
    return img


def key_light_of(
    azimuth_deg: float | int,
    elevation_deg: float | int,
    strength: float | int,
    size_deg: float | int,
) -> KeyLight | None:
    """The key light of the tab's sliders, or None at strength 0 (as `insert` without `--key-light`).

    Raises:
        ConfigError: a value out of range (`KeyLight` names `--key-light`).
    """
    if strength == 0:
        return None
    return KeyLight(
        azimuth_deg=float(azimuth_deg),
        elevation_deg=float(elevation_deg),
        strength=float(strength),
        size_deg=float(size_deg if size_deg else KEY_SIZE_DEG),
    )
