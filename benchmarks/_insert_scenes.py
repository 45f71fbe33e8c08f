"""Ground-truth scenes of `bench_insert.py`, rendered with Blender Cycles.

Run as a subprocess only (imports bpy; torch stays in the parent):

    python benchmarks/_insert_scenes.py --out DIR --seed S --threads N

For each scene of `SCENES`: a procedural object of gaffer-data's recipe (`procedural.make_object`,
index i of seed S: a Blender primitive or Suzanne with a random Principled material), normalised to
a unit box and stood on the ground (z = 0), seen by a camera 1 unit high, 3.2 units away, looking
slightly down; the world is a held-out bundled HDRI turned by a yaw. Four renders (linear float,
`RESOLUTION`), saved to `DIR/scene_{i}.npz`:

- `background`: the HDRI alone as the camera sees it (object and ground not rendered);
- `object`: the object under the HDRI, RGBA premultiplied (ground not rendered);
- `catcher`: Cycles' Shadow Catcher pass of a ground plane marked as shadow catcher, the object
  casting shadows but invisible to the camera (the background's multiplier);
- `photo`: the object under another HDRI (the object photo the insert starts from).
"""

# pyright: reportAttributeAccessIssue=false, reportMissingImports=false

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

RESOLUTION = (256, 192)
FOV_DEG = 39.6
SAMPLES = 64
CAMERA = ((0.0, -3.2, 1.0), (0.0, 0.0, 0.35))  # position, look-at
SCENES = (
    # (truth HDRI (held out: gaffer-tiny's test split), yaw in quarter turns, the photo's HDRI)
    ("courtyard", 0, "forest"),
    ("courtyard", 1, "studio"),
    ("sunset", 0, "studio"),
    ("sunset", 3, "forest"),
)


def _look_at(pos: tuple[float, ...], target: tuple[float, ...]) -> np.ndarray:
    """`[4, 4]` Blender camera-to-world (camera -z towards `target`, world z up)."""
    p, t = np.asarray(pos, float), np.asarray(target, float)
    fwd = (t - p) / np.linalg.norm(t - p)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -fwd, p
    return c2w


def envmap_pixels(name: str, quarter_turns: int) -> np.ndarray:
    """The bundled HDRI `name`, its columns rolled by `quarter_turns` quarters (a yaw)."""
    from gaffer_envmap.bundled import read_bundled_hdri

    rgb = read_bundled_hdri(name).radiance_linear
    return np.roll(rgb, quarter_turns * rgb.shape[1] // 4, axis=1).astype(np.float32)


def _read_layers(path: Path) -> dict[str, np.ndarray]:
    import OpenEXR

    out: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, channel in part.channels.items():
                out[name] = np.array(channel.pixels, dtype=np.float32)
    return out


def _pick(layers: dict[str, np.ndarray], layer: str, chans: str) -> np.ndarray:
    keys = [next(k for k in layers if k.endswith(f"{layer}.{c}")) for c in chans]
    return np.stack([layers[k] for k in keys], -1)


def render_scene(index: int, seed: int, threads: int, out: Path) -> None:
    import bpy
    from mathutils import Matrix

    from gaffer_data.render import _scene
    from gaffer_data.render.procedural import make_object

    truth_name, quarter, photo_name = SCENES[index]
    with tempfile.TemporaryDirectory() as tmp:
        glb = make_object(index, seed, Path(tmp))
        scene = _scene.reset_scene()
        _scene.import_object(glb)
        _scene.normalize_scene()
        bpy.context.view_layer.update()
        meshes = [o for o in scene.objects if o.type == "MESH"]
        zmin = min((o.matrix_world @ v.co).z for o in meshes for v in o.data.vertices)
        for o in scene.objects:
            if o.parent is None:
                o.location.z -= zmin  # stand it on the ground
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = SAMPLES
        scene.cycles.use_denoising = True
        scene.cycles.seed = 0
        scene.render.threads_mode = "FIXED"
        scene.render.threads = threads
        scene.render.resolution_x, scene.render.resolution_y = RESOLUTION
        scene.render.resolution_percentage = 100
        _scene.disable_stamps(scene)
        scene.view_layers[0].cycles.use_pass_shadow_catcher = True
        cam = bpy.data.cameras.new("cam")
        cam.sensor_fit = "HORIZONTAL"
        cam.angle = math.radians(FOV_DEG)
        cam_obj = bpy.data.objects.new("cam", cam)
        scene.collection.objects.link(cam_obj)
        c2w = _look_at(*CAMERA)
        cam_obj.matrix_world = Matrix(c2w.tolist())
        scene.camera = cam_obj
        mesh = bpy.data.meshes.new("ground")
        r = 200.0
        mesh.from_pydata([(-r, -r, 0), (r, -r, 0), (r, r, 0), (-r, r, 0)], [], [(0, 1, 2, 3)])
        ground = bpy.data.objects.new("ground", mesh)
        scene.collection.objects.link(ground)
        ground.is_shadow_catcher = True
        world, env_node = _scene.envmap_world(scene)
        world.cycles.sampling_method = "MANUAL"
        world.cycles.sample_map_resolution = 1024
        scene.world = world
        images = {
            name: _scene.image_from_pixels(
                name, np.concatenate([px, np.ones_like(px[..., :1])], -1)
            )
            for name, px in (
                ("truth", envmap_pixels(truth_name, quarter)),
                ("photo", envmap_pixels(photo_name, 0)),
            )
        }
        settings = scene.render.image_settings
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"

        def render(
            world_image: str, *, obj: bool, grd: bool, transparent: bool, camera_sees_obj: bool
        ):
            env_node.image = images[world_image]
            for o in meshes:
                o.hide_render = not obj
                o.visible_camera = camera_sees_obj
            ground.hide_render = not grd
            scene.render.film_transparent = transparent
            path = Path(tmp) / "r.exr"
            scene.render.filepath = str(path)
            bpy.ops.render.render(write_still=True)
            return _read_layers(path)

        bg = _pick(
            render("truth", obj=False, grd=False, transparent=False, camera_sees_obj=True),
            "Combined",
            "RGB",
        )
        obj = _pick(
            render("truth", obj=True, grd=False, transparent=True, camera_sees_obj=True),
            "Combined",
            "RGBA",
        )
        catcher = _pick(
            render("truth", obj=True, grd=True, transparent=True, camera_sees_obj=False),
            "Shadow Catcher",
            "RGB",
        )
        photo = _pick(
            render("photo", obj=True, grd=False, transparent=True, camera_sees_obj=True),
            "Combined",
            "RGBA",
        )
    np.savez(
        out / f"scene_{index}.npz",
        background=bg,
        object=obj,
        catcher=catcher,
        photo=photo,
        c2w=c2w,
        fov_deg=FOV_DEG,
        truth_hdri=truth_name,
        quarter_turns=quarter,
        photo_hdri=photo_name,
        object_index=index,
        seed=seed,
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--scenes", type=int, default=len(SCENES))
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for i in range(args.scenes):
        render_scene(i, args.seed, args.threads, args.out)
        print(f"scene {i} rendered", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
