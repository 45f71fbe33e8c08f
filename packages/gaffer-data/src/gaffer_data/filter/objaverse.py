"""Objaverse-style local caches as filter input: `glbs/<group>/<uid>.glb` plus the annotation JSON.

The `objaverse` package caches objects as `<cache>/hf-objaverse-v1/glbs/<group>/<uid>.glb` and their
annotations (Sketchfab metadata) as `metadata/<group>.json.gz`, each a JSON object of uid ->
annotation; `objaverse.load_annotations()` returns the same mapping, often saved as one
`annotations.json[.gz]`. This module reads such a cache without importing `objaverse` and without
downloading anything: the uid is the object id, and the licence, tags, categories and declared counts
become an `ObjaverseAnnotation` that `FilterRules` can check before any mesh is loaded.
"""

import gzip
import json
import logging
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from gaffer_data.errors import InputError

logger = logging.getLogger(__name__)

GLBS_DIR = "glbs"
ANNOTATION_NAMES = ("annotations.json", "annotations.json.gz")
"""Single-file annotations looked for at the cache root (beside `glbs/`) and in `src`."""
METADATA_DIR = "metadata"
"""The `objaverse` package's per-group annotation files: `metadata/<group>.json.gz`."""
_GZIP_MAGIC = b"\x1f\x8b"


@dataclass(frozen=True, kw_only=True)
class ObjaverseAnnotation:
    """The parts of one Objaverse annotation that filtering uses or records.

    Attributes:
        uid: the object id (the GLB's file stem).
        name: the object's title.
        license: the licence slug as annotated ("cc0", "by", "by-sa", "by-nc", "by-nd", ...).
        tags: tag names.
        categories: category names.
        face_count: faces declared by the annotation (`faceCount`, else `archives.glb.faceCount`).
        vertex_count: vertices declared by the annotation.
        animation_count: animations declared by the annotation (`animationCount`).
        file_size_bytes: GLB size declared by the annotation (`archives.glb.size`, else `fileSize`).
        like_count: Sketchfab likes (`likeCount`).
        view_count: Sketchfab views (`viewCount`).
    """

    uid: str
    name: str | None = None
    license: str | None = None
    tags: tuple[str, ...] = ()
    categories: tuple[str, ...] = ()
    face_count: int | None = None
    vertex_count: int | None = None
    animation_count: int | None = None
    file_size_bytes: int | None = None
    like_count: int | None = None
    view_count: int | None = None

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (tuples become lists when dumped)."""
        return asdict(self)

    @classmethod
    def from_entry(cls, uid: str, entry: object, *, where: str) -> "ObjaverseAnnotation":
        """Parse one annotation value of the uid -> annotation mapping.

        Args:
            uid: the mapping's key.
            entry: the mapping's value.
            where: the file, for error messages.

        Raises:
            InputError: `entry` is not an object or a field has the wrong type.
        """
        at = f"{where}, entry {uid!r}"
        if not isinstance(entry, dict):
            raise InputError(f"{at} is a {type(entry).__name__}, not an annotation object.")
        glb = entry.get("archives", {}) or {}
        glb = glb.get("glb", {}) if isinstance(glb, dict) else {}
        glb = glb if isinstance(glb, dict) else {}

        def first_count(*candidates: tuple[dict[str, Any], str]) -> int | None:
            for source, key in candidates:
                value = _count(source, key, at)
                if value is not None:
                    return value
            return None

        return cls(
            uid=uid,
            name=_text(entry, "name", at),
            license=_text(entry, "license", at),
            tags=_names(entry, "tags", at),
            categories=_names(entry, "categories", at),
            face_count=first_count((entry, "faceCount"), (glb, "faceCount")),
            vertex_count=first_count((entry, "vertexCount"), (glb, "vertexCount")),
            animation_count=_count(entry, "animationCount", at),
            file_size_bytes=first_count((glb, "size"), (entry, "fileSize")),
            like_count=_count(entry, "likeCount", at),
            view_count=_count(entry, "viewCount", at),
        )


def _text(entry: dict[str, Any], key: str, at: str) -> str | None:
    value = entry.get(key)
    if value is None or isinstance(value, str):
        return value
    raise InputError(f"{at}: `{key}`={value!r} must be a string or null.")


def _count(entry: dict[str, Any], key: str, at: str) -> int | None:
    value = entry.get(key)
    if value is None:
        return None
    # JSON writers sometimes emit 12.0 for 12; anything else is a corrupt annotation.
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputError(f"{at}: `{key}`={value!r} must be a non-negative integer or null.")
    return value


def _names(entry: dict[str, Any], key: str, at: str) -> tuple[str, ...]:
    """Names of Objaverse's `[{"name": ..., "slug": ..., "uri": ...}]` lists (plain strings too)."""
    value = entry.get(key)
    if value is None:
        return ()
    if not isinstance(value, list):
        raise InputError(f'{at}: `{key}` must be a list of {{"name": ...}} objects, got {value!r}.')
    out = []
    for item in value:
        name = item.get("name") if isinstance(item, dict) else item
        if not isinstance(name, str):
            raise InputError(
                f'{at}: `{key}` item {item!r} must be a {{"name": "..."}} object or a string.'
            )
        out.append(name)
    return tuple(out)


def find_objaverse_glbs(src: str | Path) -> Path | None:
    """The `glbs/` folder of an Objaverse-like cache at `src`, inside it, or one level below it.

    `src` may be the `glbs/` folder itself, the versioned cache folder holding it
    (`hf-objaverse-v1/`), or the cache root holding that (`~/.objaverse/`). Returns None when `src`
    is not such a cache (a plain folder of meshes).

    Raises:
        InputError: `src` holds several caches (pass one of them).
    """
    src = Path(src)
    if not src.is_dir():
        return None
    if src.name == GLBS_DIR and any(p.is_dir() for p in src.iterdir()):
        return src
    if (src / GLBS_DIR).is_dir():
        return src / GLBS_DIR
    found = sorted(p / GLBS_DIR for p in src.iterdir() if (p / GLBS_DIR).is_dir())
    if len(found) > 1:
        raise InputError(
            f"`src`={str(src)!r} holds several Objaverse caches ({[str(p.parent) for p in found]}); "
            "pass one of them."
        )
    return found[0] if found else None


def scan_objaverse(glbs: Path) -> list[tuple[str, Path]]:
    """`(uid, path)` of every `glbs/<group>/<uid>.glb`, sorted by uid.

    Raises:
        InputError: no GLB, or the same uid in two groups.
    """
    files = sorted(p for p in Path(glbs).glob("*/*") if p.suffix.lower() == ".glb" and p.is_file())
    if not files:
        raise InputError(
            f"`src`: the Objaverse cache folder `{glbs}` holds no `<group>/<uid>.glb` file."
        )
    seen: dict[str, Path] = {}
    for path in files:
        if path.stem in seen:
            raise InputError(
                f"`src`: uid {path.stem!r} appears twice (`{seen[path.stem]}`, `{path}`); "
                "remove one copy."
            )
        seen[path.stem] = path
    return sorted(seen.items())


def find_annotation_files(root: Path, *extra_folders: Path) -> tuple[Path, ...]:
    """Annotation files of a cache: `annotations.json[.gz]` in `root` (or `extra_folders`), else
    `root/metadata/*.json[.gz]` (the `objaverse` package's per-group files)."""
    for folder in (root, *extra_folders):
        for name in ANNOTATION_NAMES:
            if (folder / name).is_file():
                return (folder / name,)
    metadata = root / METADATA_DIR
    if metadata.is_dir():
        return tuple(
            sorted(
                p
                for p in metadata.iterdir()
                if p.is_file() and p.name.endswith((".json", ".json.gz"))
            )
        )
    return ()


def _read_mapping(path: Path) -> dict[str, Any]:
    fix = (
        "pass the `objaverse` package's annotations: a JSON object of uid -> annotation, "
        "optionally gzip-compressed"
    )
    try:
        raw = path.read_bytes()
        if raw[:2] == _GZIP_MAGIC:
            raw = gzip.decompress(raw)
        data = json.loads(raw.decode("utf-8"))
    except OSError as exc:  # unreadable, or a broken gzip stream (gzip.BadGzipFile)
        raise InputError(f"`annotations`={str(path)!r} cannot be read ({exc}); {fix}.") from exc
    except (EOFError, zlib.error) as exc:
        raise InputError(f"`annotations`={str(path)!r} is a truncated gzip file; {fix}.") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"`annotations`={str(path)!r} is not valid JSON ({exc}); {fix}.") from exc
    if not isinstance(data, dict):
        raise InputError(
            f"`annotations`={str(path)!r} holds a JSON {type(data).__name__}, not an object; {fix}."
        )
    return data


def read_annotations(
    paths: Iterable[Path], uids: Mapping[str, object] | set[str] | None = None
) -> dict[str, ObjaverseAnnotation]:
    """Read annotation files into `ObjaverseAnnotation`s (a later file wins for a repeated uid).

    Args:
        paths: JSON or gzip-compressed JSON files, each an object of uid -> annotation.
        uids: keep (and fully check) only these uids; None keeps all. The full Objaverse annotations
            hold ~800k objects, so a filter run keeps only the objects it scanned.

    Raises:
        InputError: a file is unreadable, not (gzip) JSON, not an object, or a kept entry is malformed;
            the message names the file and the entry.
    """
    out: dict[str, ObjaverseAnnotation] = {}
    for path in paths:
        data = _read_mapping(Path(path))
        for uid, entry in data.items():
            if uids is None or uid in uids:
                out[uid] = ObjaverseAnnotation.from_entry(
                    uid, entry, where=f"`annotations`={str(path)!r}"
                )
    logger.info("read %d annotations", len(out))
    return out
