"""Per-object features for filtering, from trimesh, pymeshlab and the glTF material JSON.

Nothing here imports bpy. `extract_features` never raises for a bad file: broken, hostile or empty
inputs come back as an `ObjectFeatures` with `error` set, which the rules turn into a rejection.
"""

import json
import math
import struct
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data.errors import missing_extra
from gaffer_data.filter.precheck import declared_face_count

NUMERIC_FEATURES = (
    "file_size_mb",
    "vertex_count",
    "face_count",
    "extent_x",
    "extent_y",
    "extent_z",
    "aspect_ratio",
    "surface_area",
    "connected_components",
    "non_manifold_edges",
    "degenerate_faces",
    "texture_count",
    "material_count",
    "base_color_luminance",
    "metallic",
    "roughness",
    "transmission",
    "alpha",
    "emission",
)
"""The numeric features, in the order the quality classifier uses them."""


@dataclass(frozen=True, kw_only=True)
class ObjectFeatures:
    """Geometry, topology and material features of one object file.

    Attributes:
        object_id: the object's id.
        path: the file.
        error: why features could not be computed (the object will be rejected), or None.
        file_size_mb: file size in MiB.
        vertex_count: vertices over all meshes.
        face_count: triangles over all meshes.
        extent_x: bounding-box side along x (source units; likewise y, z).
        aspect_ratio: largest over smallest bbox side (inf for a flat object).
        surface_area: total triangle area.
        connected_components: connected pieces (pymeshlab).
        non_manifold_edges: edges shared by more than two faces (pymeshlab).
        degenerate_faces: zero-area triangles.
        texture_count: images referenced by the file (glTF images, or trimesh textures).
        material_count: materials.
        base_color_luminance: mean Rec.709 luminance of the base colour factors (glTF), NaN when unknown.
        metallic: mean metallic factor (glTF), NaN when unknown.
        roughness: mean roughness factor (glTF), NaN when unknown.
        transmission: largest KHR_materials_transmission factor (glTF), 0 when absent.
        alpha: smallest base-colour alpha of a non-OPAQUE material, 1 when all are opaque.
        emission: largest emissive factor times KHR_materials_emissive_strength.
    """

    object_id: str
    path: str
    error: str | None = None
    file_size_mb: float = math.nan
    vertex_count: int = 0
    face_count: int = 0
    extent_x: float = math.nan
    extent_y: float = math.nan
    extent_z: float = math.nan
    aspect_ratio: float = math.nan
    surface_area: float = math.nan
    connected_components: int = 0
    non_manifold_edges: int = 0
    degenerate_faces: int = 0
    texture_count: int = 0
    material_count: int = 0
    base_color_luminance: float = math.nan
    metallic: float = math.nan
    roughness: float = math.nan
    transmission: float = 0.0
    alpha: float = 1.0
    emission: float = 0.0

    def to_json(self) -> dict[str, Any]:
        """A JSON-safe dict (NaN and inf become None)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, float) and not math.isfinite(value):
                value = None
            out[f.name] = value
        return out

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "ObjectFeatures":
        """Inverse of `to_json` (None becomes NaN for float fields; unknown keys are ignored)."""
        kwargs: dict[str, Any] = {}
        for f in fields(cls):
            if f.name not in data:
                continue
            value = data[f.name]
            if value is None and f.name not in ("error",):
                value = math.nan
            kwargs[f.name] = value
        return cls(**kwargs)

    def vector(self) -> np.ndarray:
        """`[len(NUMERIC_FEATURES)]` float64 vector for the classifier (counts log-scaled, NaN -> -1)."""
        values = []
        for name in NUMERIC_FEATURES:
            v = float(getattr(self, name))
            if name in (
                "vertex_count",
                "face_count",
                "connected_components",
                "non_manifold_edges",
                "degenerate_faces",
            ):
                v = math.log1p(max(v, 0.0))
            values.append(v if math.isfinite(v) else -1.0)
        return np.array(values, dtype=np.float64)


def _gltf_json(path: Path) -> dict[str, Any] | None:
    """The glTF JSON of a .gltf or .glb file, or None for other formats."""
    suffix = path.suffix.lower()
    if suffix == ".gltf":
        return json.loads(path.read_text(encoding="utf-8"))
    if suffix != ".glb":
        return None
    with open(path, "rb") as fh:
        header = fh.read(20)
        if len(header) < 20:
            raise ValueError("GLB file shorter than its header")
        magic, _version, _length, chunk_len, chunk_type = struct.unpack("<4sIIII", header)
        if magic != b"glTF" or chunk_type != 0x4E4F534A:
            raise ValueError("not a GLB file (bad magic or first chunk is not JSON)")
        if chunk_len > path.stat().st_size:
            raise ValueError("GLB JSON chunk is longer than the file")
        return json.loads(fh.read(chunk_len).decode("utf-8"))


def _material_features(gltf: dict[str, Any]) -> dict[str, Any]:
    materials = gltf.get("materials", []) or []
    lum, metal, rough, transmission, alpha, emission = [], [], [], [0.0], [1.0], [0.0]
    for m in materials:
        pbr = m.get("pbrMetallicRoughness", {}) or {}
        r, g, b, a = (list(pbr.get("baseColorFactor", [1.0, 1.0, 1.0, 1.0])) + [1.0] * 4)[:4]
        lum.append(0.2126 * r + 0.7152 * g + 0.0722 * b)
        metal.append(float(pbr.get("metallicFactor", 1.0)))
        rough.append(float(pbr.get("roughnessFactor", 1.0)))
        ext = m.get("extensions", {}) or {}
        transmission.append(
            float(ext.get("KHR_materials_transmission", {}).get("transmissionFactor", 0.0))
        )
        if m.get("alphaMode", "OPAQUE") != "OPAQUE":
            alpha.append(float(a))
        strength = float(
            ext.get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0)
        )
        emission.append(max(m.get("emissiveFactor", [0.0, 0.0, 0.0]) or [0.0]) * strength)

    def mean(v: list[float]) -> float:
        return float(np.mean(v)) if v else math.nan

    return {
        "material_count": len(materials),
        "texture_count": len(gltf.get("images", []) or []),
        "base_color_luminance": mean(lum),
        "metallic": mean(metal),
        "roughness": mean(rough),
        "transmission": max(transmission),
        "alpha": min(alpha),
        "emission": float(max(emission)),
    }


def _load_mesh(path: Path) -> Any:
    try:
        import trimesh
    except ImportError as exc:
        raise missing_extra("trimesh", "filter") from exc
    loaded = trimesh.load(str(path), force="scene", process=False)
    meshes = (
        [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh)]
        if isinstance(loaded, trimesh.Scene)
        else []
    )
    if not meshes:
        raise ValueError("the file holds no triangle mesh")
    mesh = trimesh.util.concatenate(meshes)
    if not isinstance(mesh, trimesh.Trimesh):  # concatenate of Trimesh parts is a Trimesh
        raise ValueError("the file's meshes could not be joined into one triangle mesh")
    # glTF splits vertices along UV and normal seams; weld them so topology counts mean something.
    mesh.merge_vertices(merge_tex=True, merge_norm=True)
    texture_count = sum(
        1 for g in meshes if getattr(getattr(g.visual, "material", None), "image", None) is not None
    )
    material_count = len(
        {id(getattr(g.visual, "material", None)) for g in meshes if hasattr(g.visual, "material")}
    )
    return mesh, texture_count, material_count


def _topology(vertices: np.ndarray, faces: np.ndarray) -> tuple[int, int]:
    """(connected components, non-manifold edges) from pymeshlab's topological measures."""
    try:
        import pymeshlab
    except ImportError as exc:
        raise missing_extra("pymeshlab", "filter") from exc
    # pymeshlab's C++ bindings ship no type stubs
    ms = pymeshlab.MeshSet()  # pyright: ignore[reportAttributeAccessIssue]
    ms.add_mesh(
        pymeshlab.Mesh(  # pyright: ignore[reportAttributeAccessIssue]
            vertex_matrix=vertices.astype(np.float64), face_matrix=faces.astype(np.int32)
        )
    )
    measures = ms.get_topological_measures()
    return int(measures["connected_components_number"]), int(measures["non_two_manifold_edges"])


def warm_up() -> None:
    """Import the mesh libraries now (a worker does it before its first time-limited object)."""
    for name in ("trimesh", "pymeshlab"):
        try:
            __import__(name)
        except ImportError:
            pass  # extract_features reports the missing extra per object


def extract_features(
    object_id: str, path: str | Path, *, max_file_mb: float = 512.0, max_faces: int = 5_000_000
) -> ObjectFeatures:
    """Compute the features of one object file; never raises for a bad file, except `MemoryError`.

    Args:
        object_id: the object's id.
        path: a mesh file trimesh can read (GLB/GLTF, OBJ, PLY, STL, OFF).
        max_file_mb: files above this are not loaded (hostile or huge): `error` says so.
        max_faces: files whose header declares more faces are not loaded, and loaded meshes above
            this skip the pymeshlab topology pass: `error` says so.

    Returns:
        The features; `error` is set when they could not all be computed.

    Raises:
        MemoryError: an allocation failed (under a worker's memory cap, the worker reports it).
    """
    path = Path(path)
    base: dict[str, Any] = {"object_id": object_id, "path": str(path)}
    try:
        size_mb = path.stat().st_size / 2**20
    except OSError as exc:
        return ObjectFeatures(**base, error=f"unreadable file: {exc}")
    base["file_size_mb"] = size_mb
    if size_mb > max_file_mb:
        return ObjectFeatures(
            **base, error=f"file is {size_mb:.0f} MiB > max_file_mb={max_file_mb}"
        )
    try:
        gltf = _gltf_json(path)
        declared = declared_face_count(path, gltf)
        if declared is not None and declared > max_faces:
            return ObjectFeatures(
                **base,
                face_count=declared,
                error=f"header declares {declared} faces > max_faces={max_faces} (not loaded)",
            )
        mesh, textures, material_count = _load_mesh(path)
        faces = np.asarray(mesh.faces)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        base.update(vertex_count=len(vertices), face_count=len(faces))
        if len(faces) > max_faces:
            return ObjectFeatures(**base, error=f"{len(faces)} faces > max_faces={max_faces}")
        if not np.isfinite(vertices).all():
            return ObjectFeatures(**base, error="non-finite vertex coordinates")
        extent = vertices.max(axis=0) - vertices.min(axis=0)
        areas = np.asarray(mesh.area_faces)
        components, non_manifold = _topology(vertices, faces)
        smallest = float(extent.min())
        base.update(
            extent_x=float(extent[0]),
            extent_y=float(extent[1]),
            extent_z=float(extent[2]),
            aspect_ratio=float(extent.max()) / smallest if smallest > 0 else math.inf,
            surface_area=float(areas.sum()),
            connected_components=components,
            non_manifold_edges=non_manifold,
            degenerate_faces=int((areas <= 1e-12 * max(float(extent.max()) ** 2, 1e-30)).sum()),
            texture_count=textures,
            material_count=material_count,
        )
        if gltf is not None:
            base.update(_material_features(gltf))
        return ObjectFeatures(**base)
    except MemoryError:
        raise  # the isolating worker turns it into "worker exceeded memory cap of N MB"
    except Exception as exc:  # hostile input: anything a loader throws becomes a rejection reason
        return ObjectFeatures(**base, error=f"{type(exc).__name__}: {str(exc)[:300]}")
