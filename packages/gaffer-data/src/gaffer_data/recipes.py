"""Object discovery and the embedded default recipe (no downloads).

The default recipe gathers data that ships inside installed packages:

- lighting: the 8 CC0 Poly Haven HDRIs bundled with gaffer-envmap (copies of bpy's studio lights);
- objects: pymeshlab's sample meshes (bunny, cow, airplane, bone, cube) and procedural Blender objects
  (primitives and Suzanne with random Principled BSDF materials, diffuse to mirror).

Building it runs a Blender subprocess for the procedural objects; this module itself imports neither bpy
nor pymeshlab (their files are found through `importlib.util.find_spec`).
"""

import importlib.util
import json
import logging
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from gaffer_data.errors import InputError, MissingDependencyError, missing_extra
from gaffer_envmap.atomic import atomic_files

logger = logging.getLogger(__name__)

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".fbx", ".blend")
"""Files that `scan_objects` picks up (what the Blender worker can import)."""

_SAMPLE_MESHES = {
    "bunny_textured": ("bunny10k_textured.obj", ("bunny10k_textured.mtl", "TextureDouble_A.png")),
    "cow": ("cow.obj", ()),
    "airplane": ("airplane.obj", ()),
    "bone": ("bone.ply", ()),
    "cube": ("cube.obj", ()),
}


def object_id_from_path(path: Path, root: Path) -> str:
    """A file-system-safe id from a path below `root`: sub-folders joined with `__`, suffix dropped."""
    rel = Path(path).relative_to(root).with_suffix("")
    return re.sub(r"[^A-Za-z0-9._-]", "_", "__".join(rel.parts))


def scan_objects(src: str | Path) -> list[tuple[str, Path]]:
    """Find the objects to render: a folder of meshes, or a `gaffer-data filter` JSONL manifest.

    Args:
        src: a folder (searched recursively for `MESH_SUFFIXES`) or a `.jsonl` file whose lines have
            `object_id`, `path` and `decision` (only "accept" lines are used).

    Returns:
        `(object_id, path)` pairs sorted by id.

    Raises:
        InputError: `src` is missing or empty, or two files map to the same id.
    """
    src = Path(src)
    if src.is_file() and src.suffix == ".jsonl":
        pairs = []
        for n, line in enumerate(src.read_text(encoding="utf-8").splitlines(), 1):
            if not line.strip():
                continue
            try:
                row = json.loads(line)
                if row.get("decision") == "accept":
                    pairs.append((str(row["object_id"]), Path(row["path"])))
            except (json.JSONDecodeError, KeyError, AttributeError) as exc:
                raise InputError(f"`{src}` line {n} is not a filter record ({exc!r}).") from exc
    elif src.is_dir():
        files = sorted(
            p
            for p in src.rglob("*")
            if p.suffix.lower() in MESH_SUFFIXES
            and p.is_file()
            # a killed `recipe` leaves only a hidden staging folder (`.partial-*`): never objects
            and not any(part.startswith(".") for part in p.relative_to(src).parts)
        )
        pairs = [(object_id_from_path(p, src), p) for p in files]
    else:
        raise InputError(
            f"`objects`={str(src)!r} is neither a folder nor a filter .jsonl manifest."
        )
    if not pairs:
        raise InputError(
            f"`objects`={str(src)!r} holds no object (suffixes: {', '.join(MESH_SUFFIXES)})."
        )
    ids = [oid for oid, _ in pairs]
    dupes = sorted({i for i in ids if ids.count(i) > 1})
    if dupes:
        raise InputError(
            f"`objects`={str(src)!r}: several files map to the ids {dupes[:5]}; rename them."
        )
    return sorted(pairs)


def bundled_envmaps() -> dict[str, Path]:
    """The 8 bundled CC0 HDRIs as {name: path} (`gaffer_envmap.bundled_hdris`, copies of bpy's)."""
    from gaffer_envmap.bundled import bundled_hdris

    return dict(bundled_hdris())


def sample_meshes() -> dict[str, list[Path]]:
    """pymeshlab's sample meshes as {name: [mesh file, side files...]} (found without importing it).

    Raises:
        MissingDependencyError: pymeshlab is not installed.
    """
    spec = importlib.util.find_spec("pymeshlab")
    if spec is None or not spec.submodule_search_locations:
        raise missing_extra("pymeshlab", "filter")
    folder = Path(next(iter(spec.submodule_search_locations))) / "tests" / "sample_meshes"
    out = {}
    for name, (mesh, extras) in _SAMPLE_MESHES.items():
        files = [folder / mesh, *(folder / e for e in extras)]
        if all(f.is_file() for f in files):
            out[name] = files
    return out


@dataclass(frozen=True, kw_only=True)
class Recipe:
    """A built recipe: a folder of objects and a folder of environment maps, ready for `render`."""

    objects: Path
    envmaps: Path


def build_default_recipe(
    out: str | Path,
    *,
    procedural: int = 8,
    seed: int = 0,
    sample_meshes_too: bool = True,
    pybullet: int = 0,
    pybullet_first: int = 0,
) -> Recipe:
    """Write the embedded default recipe into `out/objects` and `out/envmaps`.

    Args:
        out: destination folder (created; existing files are kept).
        procedural: number of procedural objects (needs bpy, run in a subprocess).
        seed: seed of the procedural shapes and materials.
        sample_meshes_too: also copy pymeshlab's sample meshes (skipped when pymeshlab is absent).
        pybullet: number of pybullet_data `random_urdfs` meshes (indices `pybullet_first`...) to add
            with random procedural materials, into `out/objects/pybullet` (needs bpy and pybullet).

    Returns:
        The recipe's folders.

    Raises:
        MissingDependencyError: bpy is needed for `procedural > 0` and is missing.
    """
    # what the procedural objects need, checked before anything is written
    if (procedural > 0 or pybullet > 0) and importlib.util.find_spec("bpy") is None:
        raise missing_extra("bpy", "render")
    if pybullet > 0 and importlib.util.find_spec("pybullet_data") is None:
        raise InputError("`--pybullet` needs pybullet's meshes: `pip install pybullet`.")
    out = Path(out)
    objects, envmaps = out / "objects", out / "envmaps"
    objects.mkdir(parents=True, exist_ok=True)
    envmaps.mkdir(parents=True, exist_ok=True)
    for name, path in bundled_envmaps().items():
        if not (envmaps / f"{name}.exr").is_file():
            shutil.copyfile(path, envmaps / f"{name}.exr")
    if sample_meshes_too:
        try:
            meshes = sample_meshes()
        except MissingDependencyError:
            logger.warning("pymeshlab is not installed: the recipe has no sample meshes")
            meshes = {}
        for name, files in meshes.items():
            folder = objects / name
            folder.mkdir(exist_ok=True)
            for f in files:
                if not (folder / f.name).is_file():
                    shutil.copyfile(f, folder / f.name)
    if procedural > 0:
        # all procedural objects or none: built in a hidden staging folder, moved at the end
        with atomic_files(objects / "procedural") as stage:
            cmd = [sys.executable, "-m", "gaffer_data.render.procedural", "--out", str(stage)]
            cmd += ["--count", str(procedural), "--seed", str(seed)]
            result = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if result.returncode != 0:
                raise InputError(f"building procedural objects failed:\n{result.stderr[-2000:]}")
    if pybullet > 0:
        with atomic_files(objects / "pybullet") as stage:
            cmd = [sys.executable, "-m", "gaffer_data.render.procedural", "--out", str(stage)]
            cmd += ["--count", str(pybullet), "--seed", str(seed)]
            cmd += ["--pybullet-first", str(pybullet_first)]
            result = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if result.returncode != 0:
                raise InputError(f"building pybullet objects failed:\n{result.stderr[-2000:]}")
    return Recipe(objects=objects, envmaps=envmaps)
