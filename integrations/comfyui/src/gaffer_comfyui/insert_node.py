"""Object insertion: an object photo relit under a background's lighting, placed, shadowed and
composited into the background (gaffer-diffusion's `insert`, Neural Gaffer §4.1), as
`gaffer-diffusion insert` composes it (cli/insert.py)."""

from typing import Any

import numpy as np

from ._boundary import library_errors
from ._convert import MASK_SENSES, check_image, object_alphas, photo_items, to_image, to_mask
from ._relight import (
    camera_pose,
    check_choice,
    check_envmap,
    check_model,
    check_number,
    sampling_for,
)
from .errors import NodeInputError
from .relight_nodes import CATEGORY, DETAIL_MODES
from .types import GAFFER_ENVMAP, GAFFER_MODEL, GafferEnvmap, GafferModel

SHADOWS = ("2d", "none")
"""`gaffer-diffusion insert --shadow` choices that are built ('cycles' is not yet)."""


class NeuralGafferInsert:
    """Put an object photo into a background photo, relit by the background's light, with a shadow."""

    CATEGORY = CATEGORY
    FUNCTION = "insert"
    RETURN_TYPES = ("IMAGE", "MASK", GAFFER_ENVMAP)
    RETURN_NAMES = ("image", "mask", "lighting")
    DESCRIPTION = (
        "The background with the object relit under its lighting (the connected `envmap` seen from "
        "the background camera, else a map built from the background photo plus an optional key "
        "light), its lowest centre point at (at_x, at_y), `height` pixels tall, with a pixel-height "
        "shadow. MASK: the placed object, in `mask_sense`. `lighting`: the map used."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        from gaffer_diffusion.insert_geometry import KEY_SIZE_DEG
        from gaffer_diffusion.photo import BACKDROP_FOV_DEG

        return {
            "required": {
                "model": (GAFFER_MODEL,),
                "object": ("IMAGE", {"tooltip": "the object's photo"}),
                "background": ("IMAGE", {"tooltip": "the photo to put it in"}),
                "mask_sense": (list(MASK_SENSES), {"default": "black = object (LoadImage)"}),
                "at_x": (
                    "INT",
                    {"default": -1, "min": -1, "max": 16384, "tooltip": "-1: centre"},
                ),
                "at_y": (
                    "INT",
                    {"default": -1, "min": -1, "max": 16384, "tooltip": "-1: the bottom third"},
                ),
                "height": (
                    "FLOAT",
                    {
                        "default": 0.0,
                        "min": 0.0,
                        "max": 16384.0,
                        "tooltip": "the object's height in background pixels; 0: as in its photo",
                    },
                ),
                "fov": (
                    "FLOAT",
                    {
                        "default": BACKDROP_FOV_DEG,
                        "min": 1.0,
                        "max": 179.0,
                        "tooltip": "the background's horizontal field of view, degrees",
                    },
                ),
                "key_azimuth": (
                    "FLOAT",
                    {
                        "default": 135.0,
                        "min": -360.0,
                        "max": 360.0,
                        "tooltip": "key light (map from the photo only): degrees clockwise from "
                        "straight ahead seen from above (90: from the right, 180: behind the camera)",
                    },
                ),
                "key_elevation": ("FLOAT", {"default": 40.0, "min": -90.0, "max": 90.0}),
                "key_strength": (
                    "FLOAT",
                    {
                        "default": 0.0,
                        "min": 0.0,
                        "max": 1000.0,
                        "tooltip": "0: no key light; else its irradiance in multiples of the photo's "
                        "mean light (3 is a typical sun)",
                    },
                ),
                "key_size": (
                    "FLOAT",
                    {"default": KEY_SIZE_DEG, "min": 0.1, "max": 90.0, "tooltip": "degrees"},
                ),
                "shadow": (list(SHADOWS), {"default": "2d"}),
                "detail": (list(DETAIL_MODES), {"default": "transfer"}),
                "seed": ("INT", {"default": 0, "min": 0, "max": 2**63 - 1}),
                "steps": (
                    "INT",
                    {"default": 0, "min": 0, "max": 1000, "tooltip": "0: the model's"},
                ),
                "guidance": (
                    "FLOAT",
                    {
                        "default": -1.0,
                        "min": -1.0,
                        "max": 100.0,
                        "tooltip": "negative: the model's",
                    },
                ),
            },
            "optional": {
                "mask": ("MASK", {"tooltip": "the object's mask, in `mask_sense`"}),
                "envmap": (GAFFER_ENVMAP, {"tooltip": "the background's HDR map, if you have it"}),
                "w2c": (
                    "STRING",
                    {
                        "default": "",
                        "tooltip": "the background camera (12 or 16 numbers or a .npy); default: "
                        "level, looking along world +y",
                    },
                ),
            },
        }

    def insert(
        self,
        model: GafferModel,
        object: Any,
        background: Any,
        mask_sense: str,
        at_x: int,
        at_y: int,
        height: float,
        fov: float,
        key_azimuth: float,
        key_elevation: float,
        key_strength: float,
        key_size: float,
        shadow: str,
        detail: str,
        seed: int,
        steps: int,
        guidance: float,
        mask: Any = None,
        envmap: Any = None,
        w2c: str = "",
    ) -> tuple[Any, Any, GafferEnvmap]:
        node = "NeuralGafferInsert"
        model = check_model(node, model)
        sampling = sampling_for(node, model, steps, guidance, seed)
        check_choice(node, "shadow", shadow, SHADOWS)
        check_choice(node, "detail", detail, DETAIL_MODES)
        fov = check_number(node, "fov", fov, 1.0, 179.0)
        height = check_number(node, "height", height, 0.0, 16384.0)
        obj = check_image(node, "object", object)
        bg = check_image(node, "background", background)
        if obj.shape[0] not in (1, bg.shape[0]):
            raise NodeInputError(
                f"{node}: `object` holds {obj.shape[0]} pictures and `background` {bg.shape[0]}; "
                "give one object, or one per background."
            )
        bh, bw = int(bg.shape[1]), int(bg.shape[2])
        for name, value, size in (("at_x", at_x, bw), ("at_y", at_y, bh)):
            if isinstance(value, bool) or not isinstance(value, int) or not -1 <= value < size:
                raise NodeInputError(
                    f"{node}: `{name}` is {value!r}; pass -1 (the default place) or a pixel in "
                    f"[0, {size - 1}] of the {bw}x{bh} background."
                )
        if (at_x < 0) != (at_y < 0):
            raise NodeInputError(
                f"{node}: `at_x` and `at_y` go together; set both to a pixel, or both to -1."
            )
        given = None if envmap is None else check_envmap(node, envmap)
        key = _key_light(node, given, key_azimuth, key_elevation, key_strength, key_size)
        pose = _background_pose(node, w2c)
        objects = photo_items(node, obj, object_alphas(node, obj, mask, mask_sense), "object")
        backgrounds = photo_items(
            node, bg, [np.zeros((bh, bw), np.float32)] * bg.shape[0], "background"
        )
        images, masks, lightings = [], [], []
        for i, back in enumerate(backgrounds):
            item = objects[i if len(objects) > 1 else 0]
            result = _insert_one(
                node, model, sampling, item, back.photo, given, key, pose, fov, shadow, detail,
                seed, (None if at_x < 0 else (at_x, at_y)), (None if height == 0 else height),
            )  # fmt: skip
            images.append(result.image)
            masks.append(result.placed.full_alpha(bh, bw))
            lightings.append(result.lighting.envmap)
        label = given.label if given is not None else "the background photo's light"
        return (
            to_image(images),
            to_mask(masks, mask_sense),
            GafferEnvmap(envmap=lightings[0], label=label),
        )


def _key_light(
    node: str,
    given: GafferEnvmap | None,
    azimuth: float,
    elevation: float,
    strength: float,
    size: float,
) -> Any:
    """The key light added to the map built from the photo (`insert --key-light`), or None."""
    strength = check_number(node, "key_strength", strength, 0.0, 1000.0)
    if strength == 0:
        return None
    if given is not None:
        raise NodeInputError(
            f"{node}: `key_strength` adds a key light to the map built from the background; a "
            "connected `envmap` brings its own light: set `key_strength` to 0 or disconnect it."
        )
    from gaffer_diffusion.insert_geometry import KeyLight

    with library_errors(node, "`key_azimuth` / `key_elevation` / `key_size`"):
        return KeyLight(
            azimuth_deg=check_number(node, "key_azimuth", azimuth, -360.0, 360.0),
            elevation_deg=check_number(node, "key_elevation", elevation, -90.0, 90.0),
            strength=strength,
            size_deg=check_number(node, "key_size", size, 0.1, 90.0),
        )


def _background_pose(node: str, w2c: str) -> Any:
    from gaffer_diffusion.insert_geometry import LEVEL_CAMERA

    if not str(w2c or "").strip():
        return LEVEL_CAMERA
    return camera_pose(node, 0.0, 0.0, w2c)


def _insert_one(
    node: str,
    model: GafferModel,
    sampling: Any,
    item: Any,
    background: Any,
    given: GafferEnvmap | None,
    key: Any,
    pose: Any,
    fov: float,
    shadow: str,
    detail: str,
    seed: int,
    at_xy: tuple[int, int] | None,
    height: float | None,
) -> Any:
    """One insertion, as `gaffer-diffusion insert` runs it (placement, lighting, then the model)."""
    import torch

    from gaffer_diffusion.insert import InsertConfig, insert_object
    from gaffer_diffusion.insert_geometry import (
        BackgroundCamera,
        InsertLighting,
        light_from_photo,
        object_extent,
        resolve_placement,
    )
    from gaffer_diffusion.photo import prepare_photo

    w, h = background.size_wh
    with library_errors(node, "`at_x` / `at_y` / `height`"):
        placement = resolve_placement(
            (w, h), object_extent(item.alpha), at_xy=at_xy, height_px=height
        )
    with library_errors(node, "`fov` / `w2c`"):
        camera = BackgroundCamera(width=w, height=h, fov_deg=fov, w2c=pose)
    if given is not None:
        lighting = InsertLighting(envmap=given.envmap, camera=camera, source=given.label)
    else:
        with library_errors(node, "`background`"):
            env = light_from_photo(background.rgb, camera, key)
        lighting = InsertLighting(envmap=env, camera=camera, key_light=key, source="photo")
    with library_errors(node, "`object` / `mask`"):
        prepared = prepare_photo(item.photo, item.alpha, size=model.size, compat=model.compat)
    config = InsertConfig(shadow=shadow, detail=detail, compat=model.compat, seed=int(seed))  # type: ignore[arg-type]
    with torch.no_grad(), library_errors(node, "insert"):
        return insert_object(
            model.pipe,
            sampling,
            prepared=prepared,
            background=background,
            lighting=lighting,
            placement=placement,
            config=config,
        )
