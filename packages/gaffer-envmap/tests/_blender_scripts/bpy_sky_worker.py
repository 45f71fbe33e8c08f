"""Blender worker for tests/test_sky.py: run as a script, `python bpy_sky_worker.py job.json`.

Runs in its own process (bpy must not share a process with libraries that break it) and imports
nothing from gaffer. The job file is JSON:

    {"threads": 2, "result": "result.json",
     "renders": [{"out": "sky.exr", "width": 128, "height": 64, "sky_type": "MULTIPLE_SCATTERING",
                  "sun_elevation_deg": 30.0, "sun_rotation_deg": 90.0, "sun_size_deg": 6.0,
                  "turbidity": 3.0}]}

Each render: the world is Blender's Sky Texture (`ShaderNodeTexSky`) of that type and sun, baked to a
lat-long EXR by an equirectangular panoramic camera at the origin with Euler XYZ (90, 0, -90), the
camera under which Blender's panorama has the Environment Texture's layout (tests/test_blender_agreement.py,
1a); Cycles, 1 sample, box filter of width 0.01 px (one point sample at each pixel centre).
"""

import json
import math
import sys

import bpy


def main() -> None:
    with open(sys.argv[1]) as f:
        job = json.load(f)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 0.01
    scene.render.threads_mode = "FIXED"
    scene.render.threads = int(job.get("threads", 2))
    scene.render.resolution_percentage = 100
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGB"
    settings.color_depth = "32"
    world = bpy.data.worlds.new("sky")
    scene.world = world
    world.cycles.sampling_method = "NONE"
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    sky = nodes.new("ShaderNodeTexSky")
    background = nodes.new("ShaderNodeBackground")
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(sky.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])
    data = bpy.data.cameras.new("pano")
    data.type = "PANO"
    data.panorama_type = "EQUIRECTANGULAR"
    cam = bpy.data.objects.new("pano", data)
    scene.collection.objects.link(cam)
    cam.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)
    scene.camera = cam
    done = []
    for item in job["renders"]:
        sky.sky_type = item["sky_type"]
        if hasattr(sky, "sun_disc"):
            sky.sun_disc = True
        if hasattr(sky, "sun_size"):
            sky.sun_size = math.radians(float(item.get("sun_size_deg", 0.545)))
        if hasattr(sky, "sun_elevation"):
            sky.sun_elevation = math.radians(float(item["sun_elevation_deg"]))
        if hasattr(sky, "sun_rotation"):
            sky.sun_rotation = math.radians(float(item["sun_rotation_deg"]))
        if hasattr(sky, "turbidity"):
            sky.turbidity = float(item.get("turbidity", 3.0))
        if item["sky_type"] in ("PREETHAM", "HOSEK_WILKIE"):
            # the old models take the sun as a direction vector (x, y, z)
            el = math.radians(float(item["sun_elevation_deg"]))
            az = math.radians(float(item["sun_rotation_deg"]))
            sky.sun_direction = (
                math.cos(el) * math.sin(az),
                math.cos(el) * math.cos(az),
                math.sin(el),
            )
        scene.render.resolution_x = int(item["width"])
        scene.render.resolution_y = int(item["height"])
        scene.render.filepath = item["out"]
        scene.render.use_file_extension = False
        bpy.ops.render.render(write_still=True)
        done.append({"out": item["out"], "sky_type": sky.sky_type})
    with open(job["result"], "w") as f:
        json.dump({"blender_version": bpy.app.version_string, "renders": done}, f)


if __name__ == "__main__":
    main()
