"""Face counts a file declares in its header, read before any mesh is loaded.

A hostile file can be small on disk yet expand into a huge mesh (a PLY or glTF header, an STL count),
and loading it is what costs memory. `declared_face_count` reads only headers (or streams an OBJ's
lines in fixed-size chunks), so `extract_features` can reject such a file without loading it. The
count is a lower bound (glTF nodes that instance a mesh twice and OBJ polygons count once); `None`
means the format gives no cheap count.
"""

import re
import struct
from pathlib import Path
from typing import Any

_CHUNK = 1 << 20
_PLY_FACES = re.compile(rb"^element\s+face\s+(\d+)\s*$", re.MULTILINE)
# glTF primitive modes: 4 triangles, 5 strip, 6 fan; points and lines have no faces.
_TRIANGLES, _STRIP, _FAN = 4, 5, 6


def _gltf_faces(gltf: dict[str, Any]) -> int:
    accessors = gltf.get("accessors", []) or []

    def count(index: object) -> int:
        if not isinstance(index, int) or not 0 <= index < len(accessors):
            return 0
        value = accessors[index].get("count", 0)
        return value if isinstance(value, int) and value > 0 else 0

    total = 0
    for mesh in gltf.get("meshes", []) or []:
        for prim in mesh.get("primitives", []) or []:
            n = count(prim.get("indices")) or count((prim.get("attributes") or {}).get("POSITION"))
            mode = prim.get("mode", _TRIANGLES)
            if mode == _TRIANGLES:
                total += n // 3
            elif mode in (_STRIP, _FAN):
                total += max(n - 2, 0)
    return total


def _ply_faces(path: Path) -> int | None:
    with open(path, "rb") as fh:
        header = fh.read(65536)
    end = header.find(b"end_header")
    match = _PLY_FACES.search(header[: end if end >= 0 else len(header)])
    return int(match.group(1)) if match else None


def _stl_faces(path: Path) -> int | None:
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(84)
    if len(head) < 84:
        return None
    (n,) = struct.unpack("<I", head[80:84])
    return n if size == 84 + 50 * n else None  # otherwise ASCII STL: no cheap count


def _off_faces(path: Path) -> int | None:
    with open(path, "rb") as fh:
        lines = [ln.split(b"#")[0].split() for ln in fh.read(4096).splitlines()]
    words = [w for ln in lines for w in ln]
    if not words or not words[0].endswith(b"OFF"):
        return None
    try:
        return int(words[2])  # OFF, then V F E
    except (IndexError, ValueError):
        return None


def _obj_faces(path: Path) -> int:
    """Lines starting with `f ` (streamed, so memory stays one chunk whatever the file size)."""
    total, previous = 0, b"\n"  # a leading "\n" counts a face on line 1
    with open(path, "rb") as fh:
        while block := fh.read(_CHUNK):
            # The 2-byte tail catches a match split across chunks; it cannot hold a whole one.
            total += (previous[-2:] + block).count(b"\nf ")
            previous = block
    return total


def declared_face_count(path: Path, gltf: dict[str, Any] | None = None) -> int | None:
    """Faces the file declares, from headers only; None when its format has no cheap count.

    Args:
        path: the mesh file.
        gltf: the already parsed glTF JSON of a .gltf/.glb file (None for other formats).
    """
    suffix = path.suffix.lower()
    if gltf is not None:
        return _gltf_faces(gltf)
    readers = {".ply": _ply_faces, ".stl": _stl_faces, ".off": _off_faces, ".obj": _obj_faces}
    reader = readers.get(suffix)
    return None if reader is None else reader(path)
