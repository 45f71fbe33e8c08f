"""Blender scene construction for the worker (imports bpy: only ever loaded inside a worker process)."""

# pyright: reportAttributeAccessIssue=false, reportMissingImports=false
# (bpy and mathutils are C extension modules without type stubs: their attributes are made at run
# time by Blender's RNA, so pyright cannot see them. Everything else here is checked.)

import logging
import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Vector

from gaffer_data.config import RenderConfig
from gaffer_data.errors import InputError

logger = logging.getLogger(__name__)

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".fbx", ".blend")


def reset_scene() -> bpy.types.Scene:
    """Start from an empty factory scene (no cube, light or camera)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def import_object(path: Path) -> None:
    """Import a mesh file into the current scene, then drop its cameras and lights.

    Raises:
        InputError: unsupported suffix, or the file holds no mesh.
    """
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(f"`{path}` does not exist; check the `--objects` folder.")
    try:
        _import_file(path, suffix)
    except RuntimeError as exc:  # bpy import operators raise RuntimeError on unreadable files
        raise InputError(f"`{path}` could not be imported by Blender: {str(exc).strip()}") from exc
    for obj in list(bpy.context.scene.objects):
        if obj.type in ("CAMERA", "LIGHT", "LIGHT_PROBE", "SPEAKER"):
            bpy.data.objects.remove(obj, do_unlink=True)
    if not any(o.type == "MESH" for o in bpy.context.scene.objects):
        raise InputError(f"`{path}` holds no mesh object; nothing to render.")


def _import_file(path: Path, suffix: str) -> None:
    if suffix in (".glb", ".gltf"):
        bpy.ops.import_scene.gltf(filepath=str(path))
    elif suffix == ".obj":
        bpy.ops.wm.obj_import(filepath=str(path))
    elif suffix == ".ply":
        bpy.ops.wm.ply_import(filepath=str(path))
    elif suffix == ".stl":
        bpy.ops.wm.stl_import(filepath=str(path))
    elif suffix == ".fbx":
        bpy.ops.import_scene.fbx(filepath=str(path))
    elif suffix == ".blend":
        with bpy.data.libraries.load(str(path), link=False) as (src, dst):
            dst.objects = list(src.objects)
        for obj in dst.objects:
            if obj is not None:
                bpy.context.scene.collection.objects.link(obj)
    else:
        raise InputError(
            f"`{path}` has an unsupported suffix {suffix!r}; use one of {MESH_SUFFIXES}."
        )


def normalize_scene() -> tuple[float, tuple[float, float, float]]:
    """Scale and move every object so the meshes' world bounding box is centred with largest side 1.

    Returns:
        `(scale, center)` with `p_new = scale * (p_old - center)`.

    Raises:
        InputError: the meshes have no extent (all vertices coincide).
    """
    bpy.context.view_layer.update()
    corners = [
        obj.matrix_world @ Vector(c)
        for obj in bpy.context.scene.objects
        if obj.type == "MESH"
        for c in obj.bound_box
    ]
    pts = np.array([[c.x, c.y, c.z] for c in corners])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = float((hi - lo).max())
    if not math.isfinite(extent) or extent <= 0.0:
        raise InputError(
            "the object has a zero-size or non-finite bounding box; it cannot be normalised."
        )
    scale = 1.0 / extent
    center = (lo + hi) / 2.0
    transform = Matrix.Scale(scale, 4) @ Matrix.Translation(Vector((-center).tolist()))
    for obj in bpy.context.scene.objects:
        if obj.parent is None:
            obj.matrix_world = transform @ obj.matrix_world
    bpy.context.view_layer.update()
    cx, cy, cz = (float(c) for c in center)
    return scale, (cx, cy, cz)


def configure_cycles(scene: bpy.types.Scene, config: RenderConfig, threads: int) -> None:
    """Apply the render config to Cycles (CPU) and colour management."""
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.samples = config.samples
    cyc.use_denoising = config.denoise
    if config.denoise:
        cyc.denoiser = "OPENIMAGEDENOISE"
    cyc.use_adaptive_sampling = config.adaptive_threshold > 0
    if config.adaptive_threshold > 0:
        cyc.adaptive_threshold = config.adaptive_threshold
    cyc.seed = config.cycles_seed
    cyc.use_animated_seed = False
    cyc.filter_width = config.filter_width
    b = config.bounces
    cyc.max_bounces = b.max_bounces
    cyc.diffuse_bounces = b.diffuse
    cyc.glossy_bounces = b.glossy
    cyc.transparent_max_bounces = b.transparent
    cyc.transmission_bounces = b.transmission
    scene.render.resolution_x = scene.render.resolution_y = config.resolution
    scene.render.resolution_percentage = 100
    scene.render.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        scene.render.threads = threads
    scene.view_settings.view_transform = config.view_transform
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.display_settings.display_device = "sRGB"
    disable_stamps(scene)


# Blender's metadata stamps (`RenderSettings.use_stamp_*`): each one also writes a field into the
# EXR/PNG header of every saved render, even with burn-in (`use_stamp`) off.
_STAMP_FLAGS = (
    "use_stamp",
    "use_stamp_date",
    "use_stamp_time",
    "use_stamp_render_time",
    "use_stamp_frame",
    "use_stamp_frame_range",
    "use_stamp_memory",
    "use_stamp_hostname",
    "use_stamp_camera",
    "use_stamp_lens",
    "use_stamp_scene",
    "use_stamp_marker",
    "use_stamp_filename",
    "use_stamp_sequencer_strip",
    "use_stamp_note",
)


def disable_stamps(scene: bpy.types.Scene) -> None:
    """Turn every metadata stamp off, so saved images carry no date, render time, frame or file name.

    Byte-reproducible renders need it: the date and render-time fields differ from run to run. Cycles'
    own timing statistics have no switch; `gaffer_data.render._metadata` strips them after saving.
    """
    for flag in _STAMP_FLAGS:
        if hasattr(scene.render, flag):
            setattr(scene.render, flag, False)


def add_camera(scene: bpy.types.Scene, config: RenderConfig) -> bpy.types.Object:
    """A camera with the config's lens and sensor width (sensor fit AUTO)."""
    cam = bpy.data.cameras.new("gaffer_camera")
    cam.lens = config.camera.lens_mm
    cam.sensor_width = config.camera.sensor_mm
    cam.sensor_fit = "AUTO"
    obj = bpy.data.objects.new("gaffer_camera", cam)
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def set_camera_pose(camera: bpy.types.Object, c2w_blender: np.ndarray) -> None:
    """Place the camera with a `[4, 4]` camera-to-world matrix (Blender camera axes)."""
    camera.matrix_world = Matrix([list(map(float, row)) for row in c2w_blender])


def envmap_world(
    scene: bpy.types.Scene,
) -> tuple[bpy.types.World, bpy.types.ShaderNodeTexEnvironment]:
    """A world of an equirectangular Environment Texture (Blender's default mapping) into a Background."""
    world = bpy.data.worlds.new("gaffer_envmap")
    tree = _world_tree(world)
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.projection = "EQUIRECTANGULAR"
    env.interpolation = "Linear"
    background = tree.nodes["Background"]
    tree.links.new(env.outputs["Color"], background.inputs["Color"])
    return world, env


def grey_world(level: float) -> bpy.types.World:
    """A uniform grey world of linear level `level` (the area-light renders, paper: 0.35)."""
    world = bpy.data.worlds.new("gaffer_grey")
    background = _world_tree(world).nodes["Background"]
    background.inputs["Color"].default_value = (level, level, level, 1.0)
    background.inputs["Strength"].default_value = 1.0
    return world


def _world_tree(world: bpy.types.World) -> bpy.types.NodeTree:
    # bpy 5.0 creates world node trees on demand; `use_nodes` is deprecated (removed in 6.0).
    if world.node_tree is None:
        world.use_nodes = True
    tree = world.node_tree
    if "Background" not in tree.nodes:
        bg = tree.nodes.new("ShaderNodeBackground")
        out = tree.nodes.new("ShaderNodeOutputWorld")
        tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
    return tree


def add_area_light(scene: bpy.types.Scene) -> bpy.types.Object:
    """A square 1 m area light facing down (-z); position, energy and scale are set per view."""
    light = bpy.data.lights.new("gaffer_area", type="AREA")
    light.size = 1.0
    obj = bpy.data.objects.new("gaffer_area", light)
    scene.collection.objects.link(obj)
    return obj


def enable_passes(scene: bpy.types.Scene, enabled: bool) -> None:
    """Turn the normal, diffuse-colour (albedo) and depth passes on or off."""
    layer = scene.view_layers[0]
    layer.use_pass_normal = enabled
    layer.use_pass_diffuse_color = enabled
    layer.use_pass_z = enabled


def load_envmap_pixels(path: Path) -> np.ndarray:
    """`[He, We, 4]` float32 pixels of an image file as Blender loads it, rows top-down."""
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        width, height = image.size
        channels = image.channels
        flat = np.empty(width * height * channels, dtype=np.float32)
        image.pixels.foreach_get(flat)
    finally:
        bpy.data.images.remove(image)
    pixels = flat.reshape(height, width, channels)[::-1]
    if channels == 3:
        pixels = np.concatenate([pixels, np.ones_like(pixels[..., :1])], axis=-1)
    return np.ascontiguousarray(pixels[..., :4])


def image_from_pixels(name: str, pixels: np.ndarray) -> bpy.types.Image:
    """A float (scene-linear) Blender image from `[H, W, 4]` top-down pixels."""
    height, width = pixels.shape[:2]
    image = bpy.data.images.new(name, width=width, height=height, alpha=True, float_buffer=True)
    bottom_up = np.ascontiguousarray(pixels[::-1], dtype=np.float32)
    image.pixels.foreach_set(bottom_up.ravel())
    image.update()
    return image
