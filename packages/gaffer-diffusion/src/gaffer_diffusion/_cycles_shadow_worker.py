"""The Blender worker of `--shadow cycles` (`gaffer_diffusion.insert_shadow_cycles`). Run as a
subprocess only, as gaffer-data runs its render workers:

    python -m gaffer_diffusion._cycles_shadow_worker --job JOB.npz --out OUT.npz [--threads N]

It imports bpy, numpy and OpenEXR, never torch or the rest of gaffer-diffusion (bpy stays out of the
parent process, which may have no bpy at all). The job holds the world map, the proxy mesh, the
camera and the render settings; the worker renders Cycles' Shadow Catcher pass of a ground plane
(a shadow catcher) under the map, the proxy invisible to the camera but casting shadows, and writes
the pass of the border it rendered to OUT.npz (atomically: a temporary name, then renamed). Progress
and errors are lines on stdout starting with `GAFFER_EVENT ` followed by JSON, as in
`gaffer_data.render.worker`. Exit codes: 0 done, 2 bad job, 3 bpy missing, 1 other errors.
"""

# pyright: reportAttributeAccessIssue=false, reportMissingImports=false
# (bpy is a C extension module without type stubs: its attributes are made at run time by Blender's
# RNA, so pyright cannot see them. Everything else here is checked.)

import argparse
import ctypes
import json
import math
import os
import signal
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

# `emit` and `_die_with_parent` repeat gaffer_data.render.worker's on purpose: the import contracts
# (pyproject.toml, [tool.importlinter]) forbid gaffer_diffusion -> gaffer_data outside training,
# evaluation and the demo, and gaffer_data.render everywhere, and gaffer_data may not import
# gaffer_diffusion; the only package both may import is gaffer_envmap, the lighting-map leaf, where a
# subprocess event protocol does not belong (and this worker imports nothing of the gaffer packages).
EVENT_PREFIX = "GAFFER_EVENT "


def emit(event: str, **fields: Any) -> None:
    """One progress event line on stdout (the parent parses these)."""
    sys.stdout.write(EVENT_PREFIX + json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


def _die_with_parent() -> None:
    # Linux: SIGKILL when the parent dies, so no orphan Blender keeps a core busy.
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        return
    if os.getppid() == 1:
        os._exit(1)


def _world(bpy: Any, scene: Any, env: np.ndarray) -> None:
    """The map as an equirectangular Environment Texture with Blender's default mapping (the map is
    in the Blender convention, as gaffer-data renders it), importance-sampled at its own width."""
    height, width = env.shape[:2]
    rgba = np.concatenate([env[..., :3], np.ones_like(env[..., :1])], -1)
    image = bpy.data.images.new("gaffer_env", width=width, height=height, float_buffer=True)
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1], np.float32).ravel())
    image.update()
    world = bpy.data.worlds.new("gaffer_env")
    if world.node_tree is None:  # bpy 5.0 makes world node trees on demand
        world.use_nodes = True
    tree = world.node_tree
    if tree is None:
        raise RuntimeError("Blender made no node tree for the world; is this bpy 5.0?")
    if "Background" not in tree.nodes:
        bg = tree.nodes.new("ShaderNodeBackground")
        out = tree.nodes.new("ShaderNodeOutputWorld")
        tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
    tex = tree.nodes.new("ShaderNodeTexEnvironment")
    tex.image = image
    tex.interpolation = "Linear"
    tree.links.new(tex.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    # a small key light (a few pixels of the map) is only found if the sampling map is as fine
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = int(width)
    scene.world = world


def _mesh(bpy: Any, scene: Any, name: str, verts: np.ndarray, faces: np.ndarray) -> Any:
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts.astype(float).tolist(), [], faces.astype(int).tolist())
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    return obj


def _material(bpy: Any, name: str, colour: tuple[float, float, float]) -> Any:
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:
        mat.use_nodes = True
    if mat.node_tree is None:
        raise RuntimeError("Blender made no node tree for a material; is this bpy 5.0?")
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
        bsdf.inputs["Roughness"].default_value = 1.0
    return mat


def render(job: dict[str, np.ndarray], threads: int) -> np.ndarray:
    """Render the job's Shadow Catcher pass; returns `[h, w, 3]` float32 of the border, top-down."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.samples = int(job["samples"])
    cyc.use_adaptive_sampling = False
    cyc.seed = int(job["seed"])
    cyc.use_denoising = bool(job["denoise"])
    if cyc.use_denoising:
        try:
            cyc.denoiser = "OPENIMAGEDENOISE"
        except TypeError:  # a build without OpenImageDenoise: render without denoising
            cyc.use_denoising = False
    scene.render.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        scene.render.threads = threads
    scene.render.film_transparent = True
    rw, rh = (int(v) for v in job["resolution"])
    scene.render.resolution_x, scene.render.resolution_y = rw, rh
    scene.render.resolution_percentage = 100
    x0, x1, y0, y1 = (float(v) for v in job["border"])  # Blender's: fractions, y from the bottom
    scene.render.use_border = True
    scene.render.use_crop_to_border = True
    scene.render.border_min_x, scene.render.border_max_x = x0, x1
    scene.render.border_min_y, scene.render.border_max_y = y0, y1
    scene.view_layers[0].cycles.use_pass_shadow_catcher = True
    _world(bpy, scene, np.asarray(job["envmap"], np.float32))

    cam = bpy.data.cameras.new("gaffer_camera")
    cam.sensor_fit = "HORIZONTAL"
    cam.angle = math.radians(float(job["fov_deg"]))
    cam.clip_start, cam.clip_end = 1e-3, 1e5
    cam_obj = bpy.data.objects.new("gaffer_camera", cam)
    scene.collection.objects.link(cam_obj)
    from mathutils import Matrix

    cam_obj.matrix_world = Matrix([list(map(float, r)) for r in np.asarray(job["c2w"])])
    scene.camera = cam_obj

    ground = _mesh(bpy, scene, "gaffer_ground", job["ground_verts"], job["ground_faces"])
    ground.is_shadow_catcher = True
    ground.data.materials.append(_material(bpy, "gaffer_ground", (0.8, 0.8, 0.8)))
    proxy = _mesh(bpy, scene, "gaffer_proxy", job["proxy_verts"], job["proxy_faces"])
    # invisible to the camera, but it shadows the ground and hides its sky (the contact shadow), and
    # throws back the light a diffuse object of the job's albedo would (a black proxy's shadow is
    # too dark next to Blender's truth, whose object reflects light onto the ground)
    proxy.visible_camera = False
    r, g, b = (float(c) for c in job.get("proxy_albedo", np.zeros(3)))
    proxy.data.materials.append(_material(bpy, "gaffer_proxy", (r, g, b)))

    with tempfile.TemporaryDirectory(prefix="gaffer_cycles_shadow_") as tmp:
        settings = scene.render.image_settings
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"
        path = Path(tmp) / "shadow.exr"
        scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True)
        return _read_shadow_catcher(path)


def _read_shadow_catcher(path: Path) -> np.ndarray:
    import OpenEXR

    channels: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, channel in part.channels.items():
                channels[name] = np.array(channel.pixels, dtype=np.float32)
    picked = []
    for c in "RGB":
        key = next((k for k in channels if k.endswith(f"Shadow Catcher.{c}")), None)
        if key is None:
            raise RuntimeError(f"the render has no `Shadow Catcher.{c}` pass; is this bpy 5.0?")
        picked.append(channels[key])
    return np.stack(picked, -1)


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m gaffer_diffusion._cycles_shadow_worker`."""
    parser = argparse.ArgumentParser(prog="python -m gaffer_diffusion._cycles_shadow_worker")
    parser.add_argument("--job", required=True, type=Path, help="the job (.npz)")
    parser.add_argument("--out", required=True, type=Path, help="where the pass goes (.npz)")
    parser.add_argument("--threads", type=int, default=0, help="Cycles threads (0: all cores)")
    args = parser.parse_args(argv)
    _die_with_parent()
    try:
        import bpy  # noqa: F401
    except ImportError:
        emit("error", kind="bpy", message='bpy is not installed; pip install "gaffer-data[render]"')
        return 3
    start = time.perf_counter()
    try:
        with np.load(args.job) as data:
            job = {k: data[k] for k in data.files}
    except (OSError, ValueError, KeyError) as exc:
        emit("error", kind="input", message=f"unreadable job {args.job}: {exc}")
        return 2
    try:
        shadow = render(job, args.threads)
        tmp = args.out.with_name(args.out.name + ".part.npz")
        np.savez(tmp, shadow=shadow)
        os.replace(tmp, args.out)
    except Exception as exc:  # the parent reports it in one line; the trace goes to stderr
        import traceback

        traceback.print_exc()
        emit("error", kind=type(exc).__name__, message=str(exc))
        return 1
    emit("done", seconds=time.perf_counter() - start)
    return 0


if __name__ == "__main__":
    sys.exit(main())
