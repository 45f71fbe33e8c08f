"""Insert an object photo into a background photo (Neural Gaffer §4.1, object insertion).

The paper segments the object (SAM), estimates the background's lighting (DiffusionLight), relights
the object with the diffusion model, pastes it, and adds a shadow from a shadow network. Here:

1. **Lighting.** An environment map the user has (`--envmap`, seen from the background camera's pose),
   or one built from the background photo itself (`light_from_photo`): the photo wrapped onto the
   sphere at the camera's field of view, the rest of the sphere a blurred, mirrored extension of it,
   expanded to HDR by an inverse tone curve, plus a key light added as a small disc of exact power
   (`KeyLight`). The key light is mostly outside the frame: a classical wrap put the dominant light
   about 50 degrees off (median over 8 bundled HDRIs x 4 views,
   60-degree 8-bit crops), so the key light should be given.
2. **Relighting.** The object photo is relit under that map seen from the background camera
   (`RelightPipeline`) and brought back to full resolution with the photo path's detail transfer
   (`gaffer_diffusion.photo.relit_object`).
3. **Placement.** It is scaled and moved so that its lowest centre point lands at `Placement.foot_xy`
   with `Placement.height_px` pixels of height (`place_object`).
4. **Shadow.** A pixel-height shadow (after Sheng et al., "Controllable Shadow Generation Using Pixel
   Height Maps", ECCV 2022) is cast on the ground plane from the placed mask, away from the dominant
   light, and multiplied into the background in linear light (`cast_shadow_2d`); or, with
   `shadow="cycles"`, Blender Cycles' shadow catcher renders the shadow of a proxy inflated from the
   placed mask under the same map (`insert_shadow_cycles.cast_shadow_cycles`, in a Blender worker
   process).
5. **Composite.** The object is alpha-composited over it (`composite`). Pixels away from the object and
   its shadow keep the background's bytes exactly.

Geometry: the ground is the plane z = 0 of Blender's world (z up); the background camera is a pinhole
with horizontal field of view `fov_deg` and pose `w2c` (default: level, looking along world +y, so
azimuth 0 of a key light is straight ahead, behind the object). Each object pixel stands above the
ground point under the object's lowest row (a billboard on the ground line, the pixel-height model);
the ground seen at the foot's row is foreshortened by `(foot row - horizon row) / focal length`.
"""

import time
from dataclasses import dataclass, field
from typing import Literal, assert_never

import numpy as np
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion._choices import DetailMode, PrepareCompat, ShadowMode
from gaffer_diffusion.conditioning import RelightingConditions, lighting_from_envmap
from gaffer_diffusion.errors import InputValueError, MissingDependencyError

# the geometry, lighting and shadow, importable from here too (documented in insert_geometry)
from gaffer_diffusion.insert_geometry import LEVEL_CAMERA as LEVEL_CAMERA
from gaffer_diffusion.insert_geometry import BackgroundCamera as BackgroundCamera
from gaffer_diffusion.insert_geometry import DominantLight as DominantLight
from gaffer_diffusion.insert_geometry import InsertLighting as InsertLighting
from gaffer_diffusion.insert_geometry import KeyLight as KeyLight
from gaffer_diffusion.insert_geometry import ObjectExtent as ObjectExtent
from gaffer_diffusion.insert_geometry import PlacedObject as PlacedObject
from gaffer_diffusion.insert_geometry import Placement as Placement
from gaffer_diffusion.insert_geometry import cast_shadow_2d as cast_shadow_2d
from gaffer_diffusion.insert_geometry import composite as composite
from gaffer_diffusion.insert_geometry import default_placement as default_placement
from gaffer_diffusion.insert_geometry import dominant_light as dominant_light
from gaffer_diffusion.insert_geometry import inverse_tone as inverse_tone
from gaffer_diffusion.insert_geometry import light_from_photo as light_from_photo
from gaffer_diffusion.insert_geometry import object_extent as object_extent
from gaffer_diffusion.insert_geometry import place_object as place_object
from gaffer_diffusion.insert_geometry import resolve_placement as resolve_placement
from gaffer_diffusion.insert_shadow_cycles import (
    CyclesShadowConfig,
    cast_shadow_cycles,
    require_bpy,
)
from gaffer_diffusion.photo import Photo, PreparedPhoto, relit_object
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig

__all__ = [
    "InsertConfig",
    "InsertResult",
    "ProxyMode",
    "check_shadow",
    "insert_object",
    "relight_under",
]

ProxyMode = Literal["auto", "estimated", "mask"]
"""The proxy of `shadow="cycles"`: "estimated" (the mask and gaffer-normals' estimated normals,
`insert_relief`), "mask" (the mask inflated alone) or "auto" (estimated; the mask when the
estimator's weights are missing, and the result says so)."""


@dataclass(frozen=True, kw_only=True)
class InsertConfig:
    """How an object is inserted (besides lighting and placement).

    Attributes:
        shadow: "2d" (pixel-height shadow, default), "cycles" (Blender's shadow catcher, needs bpy)
            or "none".
        detail: "transfer" (the model's change of shading applied to the full-resolution object
            photo, default) or "resize" (the model's output upsampled).
        compat: the lighting encoding and framing the model expects (`_choices.PrepareCompat`).
        seed: sampling seed.
        cycles: how `shadow="cycles"` renders (size, samples, denoising, threads).
        proxy: the proxy `shadow="cycles"` casts its shadow from (`ProxyMode`).
    """

    shadow: ShadowMode = "2d"
    detail: DetailMode = "transfer"
    compat: PrepareCompat = "default"
    seed: int = 0
    cycles: CyclesShadowConfig = field(default_factory=CyclesShadowConfig)
    proxy: ProxyMode = "auto"


@dataclass(frozen=True, kw_only=True)
class InsertResult:
    """What `insert_object` made.

    Attributes:
        image: `[H, W, 3]` uint8 sRGB: the background at full size with the object and its shadow.
        shadow: `[H, W]` float32 factor the background was multiplied by in linear light (1: untouched).
        placed: the object as placed.
        placement: the placement used.
        lighting: the lighting used (its map is what `--save-envmap` writes).
        light: the light the shadow comes from.
        relit_model: `[3, S, S]` the model's relit crop, sRGB in [0, 1].
        shadow_seconds: seconds the shadow took (for "cycles": Blender's worker, its start included).
        proxy: for "cycles", the proxy used, as the report says it ("" otherwise).
    """

    image: np.ndarray
    shadow: np.ndarray
    placed: PlacedObject
    placement: Placement
    lighting: InsertLighting
    light: DominantLight
    relit_model: Tensor = field(repr=False)
    shadow_seconds: float = 0.0
    proxy: str = ""


def _estimator_missing() -> str | None:
    """Why the shipped normal estimator cannot load (its manifest or weights missing), or None."""
    from gaffer_diffusion.geometry.estimator import (
        ESTIMATOR_CONFIG_NAME,
        shipped_normal_estimator_path,
    )

    root = shipped_normal_estimator_path()
    for needed in (
        root / ESTIMATOR_CONFIG_NAME,
        root / "unet" / "diffusion_pytorch_model.safetensors",
    ):
        if not needed.is_file():
            return f"{needed} is missing"
    return None


def check_shadow(config: InsertConfig) -> str | None:
    """Refuse, before anything is sampled, a shadow this install cannot make.

    Returns:
        For `shadow="cycles"` with `proxy="auto"`: why the estimated proxy falls back to the mask's
        (the estimator's missing file), or None when nothing falls back.

    Raises:
        MissingDependencyError: "cycles" without bpy (naming `--shadow 2d`), or `proxy="estimated"`
            without the shipped normal estimator's weights (naming `proxy='mask'`).
    """
    if config.shadow != "cycles":
        return None
    require_bpy()
    missing = _estimator_missing() if config.proxy != "mask" else None
    if missing is not None and config.proxy == "estimated":
        raise MissingDependencyError(
            f"proxy='estimated' needs the normal estimator gaffer-normals ({missing}); "
            "reinstall gaffer-diffusion, or pass proxy='mask' (the proxy inflated from the mask)."
        )
    return missing


def relight_under(
    pipe: RelightPipeline,
    prepared: PreparedPhoto,
    lighting: InsertLighting,
    sampling: SamplingConfig,
    *,
    compat: PrepareCompat = "default",
    seed: int = 0,
) -> Float[Tensor, "3 S S"]:
    """The model's relit crop of `prepared` under `lighting` seen from the background camera."""
    size = prepared.framing.size
    maps = lighting_from_envmap(lighting.envmap, [lighting.camera.w2c], size=size, compat=compat)
    conditions = RelightingConditions(
        image=prepared.model_input.image, lighting=maps, mask=prepared.model_input.mask
    )
    return pipe(conditions, sampling, seeds=[seed]).images[0].float().cpu()


def insert_object(
    pipe: RelightPipeline,
    sampling: SamplingConfig,
    *,
    prepared: PreparedPhoto,
    background: Photo,
    lighting: InsertLighting,
    placement: Placement,
    config: InsertConfig | None = None,
) -> InsertResult:
    """Relight `prepared` (the object photo) under `lighting`, place it in `background`, cast its
    shadow and composite (the module docstring has the steps).

    Raises:
        MissingDependencyError: `config.shadow == "cycles"` without bpy, or with
            `config.proxy == "estimated"` and no normal estimator weights (`check_shadow`, before
            sampling; "auto" falls back to the mask's proxy).
        ShadowRenderError: the Blender worker of "cycles" failed (nothing is returned).
        InputValueError: a background whose size is not the camera's.
    """
    config = config or InsertConfig()
    missing = check_shadow(config)
    w, h = background.size_wh
    if (w, h) != (lighting.camera.width, lighting.camera.height):
        raise InputValueError(
            f"The background is {w}x{h} but the camera is "
            f"{lighting.camera.width}x{lighting.camera.height}; build the camera from the background."
        )
    relit = relight_under(
        pipe, prepared, lighting, sampling, compat=config.compat, seed=config.seed
    )
    extent = object_extent(prepared.alpha)
    relit_obj = relit_object(prepared, relit, detail=config.detail)
    placed = place_object(relit_obj, extent, placement, (h, w))
    light = dominant_light(lighting.envmap, lighting.key_light)
    start = time.perf_counter()
    proxy = ""
    match config.shadow:
        case "2d":
            shadow = cast_shadow_2d(placed, lighting.camera, light)
        case "none":
            shadow = np.ones((h, w), np.float32)
        case "cycles":
            relief = None
            if config.proxy == "mask":
                proxy = "a proxy inflated from the mask"
            elif missing is not None:
                proxy = f"a proxy inflated from the mask (no estimated normals: {missing})"
            else:
                from gaffer_diffusion.insert_relief import estimated_relief

                relief = estimated_relief(prepared, relit_obj.box, extent, placement, (h, w))
                proxy = f"a proxy from the mask and the normals estimated by {relief.source}"
            shadow = cast_shadow_cycles(
                placed,
                lighting,
                light,
                config.cycles,
                relief=None if relief is None else relief.height,
            ).factor
        case _:
            assert_never(config.shadow)
    shadow_seconds = time.perf_counter() - start
    return InsertResult(
        image=composite(background, placed, shadow),
        shadow=shadow,
        placed=placed,
        placement=placement,
        lighting=lighting,
        light=light,
        relit_model=relit,
        shadow_seconds=shadow_seconds,
        proxy=proxy,
    )
