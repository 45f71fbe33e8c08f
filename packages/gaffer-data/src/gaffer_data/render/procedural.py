"""Procedural test objects: Blender primitives and Suzanne with random Principled BSDF materials.

Run as a subprocess only (imports bpy):

    python -m gaffer_data.render.procedural --out DIR [--count 8] [--seed 0]

Writes `DIR/procedural_{NNN}.glb`, one object per file, materials from diffuse to mirror (base colour,
metallic, roughness, sometimes transmission or emission survive the glTF export). Objects are exported
to GLB so that renders of them are bit-identical across processes (imported meshes are; meshes built
from Python in each process are not, by up to ~4e-3, through their vertex normals).
"""

# pyright: reportAttributeAccessIssue=false, reportMissingImports=false
# (bpy and mathutils are C extension modules without type stubs: their attributes are made at run
# time by Blender's RNA, so pyright cannot see them. Everything else here is checked.)

import argparse
import colorsys
import logging
import math
import sys
from pathlib import Path

import numpy as np

from gaffer_data._atomic import atomic_write

logger = logging.getLogger("gaffer_data.render.procedural")

SHAPES = ("monkey", "uv_sphere", "ico_sphere", "cube", "cylinder", "cone", "torus")


def _add_shape(shape: str) -> None:
    import bpy

    ops = bpy.ops.mesh
    if shape == "monkey":
        ops.primitive_monkey_add()
        bpy.ops.object.modifier_add(type="SUBSURF")
        bpy.context.object.modifiers[-1].levels = 1
        bpy.ops.object.modifier_apply(modifier=bpy.context.object.modifiers[-1].name)
    elif shape == "uv_sphere":
        ops.primitive_uv_sphere_add(segments=48, ring_count=24)
    elif shape == "ico_sphere":
        ops.primitive_ico_sphere_add(subdivisions=2)
    elif shape == "cube":
        ops.primitive_cube_add()
        bpy.ops.object.modifier_add(type="BEVEL")
        bpy.context.object.modifiers[-1].width = 0.1
        bpy.context.object.modifiers[-1].segments = 3
        bpy.ops.object.modifier_apply(modifier=bpy.context.object.modifiers[-1].name)
    elif shape == "cylinder":
        ops.primitive_cylinder_add(vertices=48)
    elif shape == "cone":
        ops.primitive_cone_add(vertices=48)
    else:
        ops.primitive_torus_add(major_segments=48, minor_segments=16)
    if shape in ("monkey", "uv_sphere", "torus", "cylinder", "cone"):
        bpy.ops.object.shade_smooth()


def _random_material(rng: np.random.Generator, name: str) -> object:
    import bpy

    mat = bpy.data.materials.new(name)
    bsdf = mat.node_tree.nodes["Principled BSDF"] if mat.node_tree else None
    if bsdf is None:
        mat.use_nodes = True
        bsdf = mat.node_tree.nodes["Principled BSDF"]
    r, g, b = colorsys.hsv_to_rgb(rng.uniform(), rng.uniform(0.0, 0.9), rng.uniform(0.2, 1.0))
    kind = rng.choice(
        ["diffuse", "plastic", "metal", "mirror", "glass", "emissive"],
        p=[0.3, 0.25, 0.2, 0.1, 0.1, 0.05],
    )
    metallic, roughness, transmission = 0.0, float(rng.uniform(0.5, 1.0)), 0.0
    if kind == "plastic":
        roughness = float(rng.uniform(0.05, 0.5))
    elif kind == "metal":
        metallic, roughness = 1.0, float(rng.uniform(0.1, 0.6))
    elif kind == "mirror":
        metallic, roughness = 1.0, float(rng.uniform(0.0, 0.05))
        r = g = b = float(rng.uniform(0.8, 1.0))
    elif kind == "glass":
        transmission, roughness = 1.0, float(rng.uniform(0.0, 0.2))
    bsdf.inputs["Base Color"].default_value = (r, g, b, 1.0)
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Transmission Weight"].default_value = transmission
    if kind == "emissive":
        bsdf.inputs["Emission Color"].default_value = (r, g, b, 1.0)
        bsdf.inputs["Emission Strength"].default_value = float(rng.uniform(0.5, 2.0))
    return mat


def make_object(index: int, seed: int, out: Path) -> Path:
    """Build procedural object `index` of `seed` and export it to `out/procedural_{index:03d}.glb`."""
    import bpy

    rng = np.random.default_rng([seed, index])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    shape = SHAPES[index % len(SHAPES)]
    _add_shape(shape)
    obj = bpy.context.object
    obj.scale = tuple(float(s) for s in rng.uniform(0.5, 1.5, size=3))
    obj.rotation_euler = tuple(float(a) for a in rng.uniform(0.0, 2.0 * math.pi, size=3))
    obj.data.materials.append(_random_material(rng, f"mat_{index:03d}"))
    path = out / f"procedural_{index:03d}.glb"

    def export(tmp: Path) -> None:
        bpy.ops.export_scene.gltf(filepath=str(tmp), export_format="GLB", use_selection=False)

    atomic_write(path, export)
    return path


def make_pybullet_object(mesh: Path, index: int, seed: int, out: Path) -> Path:
    """Import one of pybullet_data's `random_urdfs` meshes, give it a random material of the
    procedural family (diffuse to mirror) and a random orientation, and export it to
    `out/pybullet_{index:03d}.glb`.

    The random_urdfs shapes (1,000 faceted blobs generated for grasping research) ship inside the
    pybullet wheel under its zlib licence; they carry no material worth keeping (a flat .mtl).
    """
    import bpy

    rng = np.random.default_rng([seed, 100_000 + index])
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.obj_import(filepath=str(mesh))
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"]
    for obj in meshes:
        obj.data.materials.clear()
        obj.rotation_euler = tuple(float(a) for a in rng.uniform(0.0, 2.0 * math.pi, size=3))
    mat = _random_material(rng, f"mat_pb_{index:03d}")
    for obj in meshes:
        obj.data.materials.append(mat)
    path = out / f"pybullet_{index:03d}.glb"

    def export(tmp: Path) -> None:
        bpy.ops.export_scene.gltf(filepath=str(tmp), export_format="GLB", use_selection=False)

    atomic_write(path, export)
    return path


def pybullet_random_meshes(first: int, count: int) -> list[tuple[int, Path]]:
    """`(index, path)` of pybullet_data's `random_urdfs/NNN/NNN.obj` for NNN in first..first+count-1.

    Disjoint ranges give disjoint splits (the model card's recipes use 0-79 train, 500-511
    validation, 750-761 test).
    """
    import pybullet_data  # pyright: ignore[reportMissingModuleSource]

    root = Path(pybullet_data.getDataPath()) / "random_urdfs"
    out = []
    for index in range(first, first + count):
        path = root / f"{index:03d}" / f"{index:03d}.obj"
        if path.is_file():
            out.append((index, path))
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m gaffer_data.render.procedural`."""
    parser = argparse.ArgumentParser(prog="python -m gaffer_data.render.procedural")
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--count", type=int, default=8)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pybullet-first", type=int, default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(name)s: %(message)s")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.pybullet_first is not None:
        for index, mesh in pybullet_random_meshes(args.pybullet_first, args.count):
            make_pybullet_object(mesh, index, args.seed, args.out)
        return 0
    for index in range(args.count):
        make_object(index, args.seed, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
