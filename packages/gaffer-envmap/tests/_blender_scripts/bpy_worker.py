"""Blender worker for tests/test_blender_agreement.py: run as a script, `python bpy_worker.py job.json`.

Runs in its own process (bpy must not share a process with libraries that break it). Imports nothing from
gaffer. The job file is JSON:

    {
      "threads": 2,
      "renders": [{"env": "in.exr", "out": "out.exr", "width": 128, "height": 64,
                   "rotation": [[...], [...], [...]], "interpolation": "Closest" | "Linear",
                   "camera": "PANO" | "PERSP", "fov_deg": 40.0}],
      "track_to": [{"location": [x, y, z]}],
      "result": "result.json"
    }

Each render: the world is an Environment Texture (equirectangular, strength 1) showing `env`; a panoramic
EQUIRECTANGULAR camera ("PANO", default) or a perspective camera ("PERSP", horizontal field of view
`fov_deg`) sits at the origin with `matrix_world` rotation = `rotation` (columns = camera x, y, z axes in
world coordinates); Cycles, 1 sample, box pixel filter of width 0.01 px (i.e. one point
sample at each pixel centre), view transform Standard, 32-bit float EXR written top row first.

Each track_to entry: a perspective camera at `location` with a TRACK_TO constraint (track -Z, up Y)
aimed at an empty at the origin, as the Objaverse/Zero123 render scripts do; its evaluated
`matrix_world` (4x4, row-major) and the 3x4 world-to-camera that the authors' script derives from it
(`rt_authors`) go to the result file.
"""

import json
import sys
import time

import bpy
from mathutils import Matrix


def _reset_scene() -> bpy.types.Scene:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    return bpy.context.scene


def _setup_render(scene: bpy.types.Scene, threads: int) -> None:
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 0.01  # minimum: every sample at the pixel centre (point sampling)
    scene.cycles.seed = 0
    scene.render.threads_mode = "FIXED"
    scene.render.threads = threads
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = 1.0
    scene.render.pixel_aspect_y = 1.0
    scene.render.film_transparent = False
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.display_settings.display_device = "sRGB"
    scene.view_settings.view_transform = "Standard"  # no AgX/Filmic (EXR is linear anyway)
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGB"
    settings.color_depth = "32"
    settings.exr_codec = "ZIP"


def _setup_world(scene: bpy.types.Scene) -> bpy.types.ShaderNodeTexEnvironment:
    world = bpy.data.worlds.new("agreement")
    scene.world = world
    # No world importance map: the scene is empty, camera rays see the background directly, and building
    # the map costs ~3 s per render on 2 cores.
    world.cycles.sampling_method = "NONE"
    if bpy.app.version < (5, 0, 0):  # 5.0 always uses nodes and deprecates the flag
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    tex = nodes.new("ShaderNodeTexEnvironment")
    tex.projection = "EQUIRECTANGULAR"
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = 1.0
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(tex.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])
    return tex


def _camera(scene: bpy.types.Scene, kind: str, fov_deg: float) -> bpy.types.Object:
    data = bpy.data.cameras.new(kind.lower())
    if kind == "PANO":
        data.type = "PANO"
        data.panorama_type = "EQUIRECTANGULAR"
        # Defaults, set explicitly: the full sphere.
        data.latitude_min, data.latitude_max = -1.5707963267948966, 1.5707963267948966
        data.longitude_min, data.longitude_max = -3.141592653589793, 3.141592653589793
    else:
        data.type = "PERSP"
        data.sensor_fit = "HORIZONTAL"
        data.angle = fov_deg * 3.141592653589793 / 180.0  # horizontal field of view
        data.shift_x = data.shift_y = 0.0
    cam = bpy.data.objects.new(kind.lower(), data)
    scene.collection.objects.link(cam)
    return cam


def _render(job: dict, threads: int) -> list[dict]:
    scene = _reset_scene()
    _setup_render(scene, threads)
    tex = _setup_world(scene)
    done = []
    for item in job:
        start = time.perf_counter()
        cam = _camera(scene, item.get("camera", "PANO"), float(item.get("fov_deg", 40.0)))
        scene.camera = cam
        image = bpy.data.images.load(item["env"], check_existing=False)
        tex.image = image
        tex.interpolation = item.get("interpolation", "Closest")
        rot = item["rotation"]
        cam.matrix_world = Matrix(
            [
                [rot[0][0], rot[0][1], rot[0][2], 0.0],
                [rot[1][0], rot[1][1], rot[1][2], 0.0],
                [rot[2][0], rot[2][1], rot[2][2], 0.0],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
        scene.render.resolution_x = int(item["width"])
        scene.render.resolution_y = int(item["height"])
        scene.render.filepath = item["out"]
        scene.render.use_file_extension = False
        bpy.ops.render.render(write_still=True)
        done.append(
            {
                "out": item["out"],
                "seconds": time.perf_counter() - start,
                "image_colorspace": image.colorspace_settings.name,
                "image_is_float": bool(image.is_float),
            }
        )
        bpy.data.images.remove(image)
    return done


def _track_to(job: list[dict]) -> list[dict]:
    scene = _reset_scene()
    target = bpy.data.objects.new("target", None)
    scene.collection.objects.link(target)
    out = []
    for item in job:
        data = bpy.data.cameras.new("persp")
        cam = bpy.data.objects.new("persp", data)
        scene.collection.objects.link(cam)
        cam.location = item["location"]
        constraint = cam.constraints.new(type="TRACK_TO")
        constraint.target = target
        constraint.track_axis = "TRACK_NEGATIVE_Z"
        constraint.up_axis = "UP_Y"
        bpy.context.view_layer.update()
        # The authors' (Zero123/Objaverse) get_3x4_RT_matrix_from_blender: R = rot^T, t = -R @ location.
        location, rotation = cam.matrix_world.decompose()[0:2]
        r_w2c = rotation.to_matrix().transposed()
        t_w2c = -1 * r_w2c @ location
        rt = [[*r_w2c[i], t_w2c[i]] for i in range(3)]
        out.append({"matrix_world": [list(row) for row in cam.matrix_world], "rt_authors": rt})
    return out


def main() -> None:
    with open(sys.argv[1]) as f:
        job = json.load(f)
    threads = int(job.get("threads", 2))
    result: dict = {"blender_version": bpy.app.version_string}
    if job.get("track_to"):
        result["track_to"] = _track_to(job["track_to"])
    if job.get("renders"):
        result["renders"] = _render(job["renders"], threads)
    with open(job["result"], "w") as f:
        json.dump(result, f)


if __name__ == "__main__":
    main()
