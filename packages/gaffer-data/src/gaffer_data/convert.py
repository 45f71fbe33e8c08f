"""`gaffer-data convert-authors`: turn the authors' released layout into a gaffer artifact.

The layout and the artifact are described in `gaffer_data.dataset.authors`. The conversion copies (or
hard-links) every file byte for byte, hashes it, writes the poses as `cameras.npz` (Blender
world-to-camera as released, plus OpenCV camera-to-world) and a manifest per object, written last.
Re-running skips objects that are already converted; an object that cannot be converted (no pose, an
image without its lighting maps, a file that is not a PNG) is recorded in `dataset.json` with the
reason, and the run goes on. Pure Python + numpy: no Blender, no torch.
"""

import dataclasses
import json
import logging
import os
import re
import shutil
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data._atomic import atomic_write, atomic_write_json, remove_stale_temporaries
from gaffer_data.dataset.authors import (
    AUTHORS_DATASET_SCHEMA,
    AUTHORS_DATASET_SCHEMA_VERSION,
    AUTHORS_OBJECT_SCHEMA,
    AUTHORS_OBJECT_SCHEMA_VERSION,
    DATASET_NAME,
    MANIFEST_NAME,
    OBJECTS_DIR,
    HdrFolder,
)
from gaffer_data.dataset.manifest import producer, sha256_file, utc_now
from gaffer_data.dataset.schema import FailureRecord, FileRecord, Intrinsics
from gaffer_data.errors import InputError
from gaffer_envmap.errors import PoseError
from gaffer_envmap.poses import W2CBlender

logger = logging.getLogger(__name__)

_LIT = re.compile(r"^(\d{3,})_(\d{3,})_(.+)\.png$")
_AREA = re.compile(r"^random_lighting_(\d{3,})\.png$")
_POSE = re.compile(r"^(\d{3,})_RT\.npy$")
_HDR_FOLDERS: tuple[HdrFolder, ...] = ("HDR_rescaled", "HDR_normalized")
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # IHDR colour type -> decoded channels


@dataclass(frozen=True, kw_only=True)
class ConvertOptions:
    """How to convert the authors' layout.

    Attributes:
        lighting: the folder holding `LDR/` and `HDR_rescaled/` (or `HDR_normalized/`), each with one
            sub-folder per object; None = the split folder itself. Maps inside the object folder
            (`<obj>/LDR/...`) are found too.
        object_ids: convert only these objects (e.g. from the authors' `val_unseen_object_list.json`);
            None = every object folder with a `{VVV}_RT.npy`.
        hardlink: hard-link instead of copying (falls back to a copy across file systems).
        lens_mm: focal length assumed for the intrinsics (the authors' 35 mm).
        sensor_mm: sensor width assumed for the intrinsics (the authors' 32 mm).
    """

    lighting: Path | None = None
    object_ids: tuple[str, ...] | None = None
    hardlink: bool = False
    lens_mm: float = 35.0
    sensor_mm: float = 32.0


@dataclass(frozen=True, kw_only=True)
class ConvertSummary:
    """What a conversion did.

    Attributes:
        converted: objects converted by this run.
        skipped_complete: objects already converted before this run.
        failed: objects that could not be converted, with reasons.
        images: environment-map images converted by this run.
    """

    converted: tuple[str, ...]
    skipped_complete: tuple[str, ...]
    failed: tuple[FailureRecord, ...]
    images: int


def png_shape(path: Path) -> tuple[tuple[int, ...], str]:
    """Decoded shape and dtype of a PNG from its IHDR chunk (no image library needed).

    Returns:
        `((H, W, C) or (H, W), "uint8" | "uint16")`.

    Raises:
        InputError: the file is not a PNG.
    """
    with open(path, "rb") as fh:
        head = fh.read(33)
    if len(head) < 33 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise InputError(f"`{path}` is not a PNG file; re-download it from the authors' release.")
    width, height, depth, color = struct.unpack(">IIBB", head[16:26])
    channels = _PNG_CHANNELS.get(color)
    if channels is None or width == 0 or height == 0:
        raise InputError(f"`{path}` has an invalid PNG header (colour type {color}).")
    shape = (height, width) if channels == 1 else (height, width, channels)
    return shape, "uint16" if depth == 16 else "uint8"


def find_authors_objects(src: Path, object_ids: Sequence[str] | None = None) -> list[Path]:
    """The object folders of an authors' split: sub-folders holding at least one `{VVV}_RT.npy`.

    Raises:
        InputError: `src` is not a folder, holds no object, or a requested id is missing.
    """
    src = Path(src)
    if not src.is_dir():
        raise InputError(
            f"`src`={str(src)!r} is not a folder; pass a split folder of the authors' release."
        )
    if object_ids is not None:
        missing = [o for o in object_ids if not (src / o).is_dir()]
        if missing:
            raise InputError(
                f"`object_ids` names {len(missing)} objects missing from `{src}` (e.g. {missing[:3]}); "
                "pass the matching split folder or drop them from the list."
            )
        return [src / o for o in object_ids]
    found = sorted(
        p for p in src.iterdir() if p.is_dir() and any(_POSE.match(f.name) for f in p.iterdir())
    )
    if not found:
        raise InputError(
            f"`src`={str(src)!r} holds no object folder with `{{VVV}}_RT.npy` files; pass a split "
            "folder such as `val_unseen/` of the authors' release."
        )
    return found


def _lighting_file(
    obj: Path, lighting: Path, kind: str, name: str
) -> tuple[Path | None, HdrFolder | None]:
    folders: tuple[str, ...] = ("LDR",) if kind == "ldr" else _HDR_FOLDERS
    for folder in folders:
        for candidate in (lighting / folder / obj.name / name, obj / folder / name):
            if candidate.is_file():
                return candidate, None if kind == "ldr" else folder  # type: ignore[return-value]
    return None, None


def _place(src: Path, dst: Path, hardlink: bool) -> None:
    """Hard-link (atomic by nature) or copy atomically `src` to `dst`."""
    if hardlink:
        dst.parent.mkdir(parents=True, exist_ok=True)
        dst.unlink(missing_ok=True)
        try:
            os.link(src, dst)
            return
        except OSError:  # another file system, or links unsupported: copy instead
            pass
    atomic_write(dst, lambda tmp: shutil.copyfile(src, tmp))


def _load_w2c(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
        return W2CBlender.from_array(arr).matrix
    except (OSError, ValueError, PoseError) as exc:
        raise InputError(f"`{path}` is not a 3x4 world-to-camera matrix ({exc}).") from exc


def _convert_object(obj: Path, dst: Path, options: ConvertOptions) -> tuple[set[str], int]:
    """Convert one object folder; returns (envmap names, image count).

    Raises:
        InputError: the object cannot be converted (the reason names the file and the fix).
    """
    lighting = Path(options.lighting) if options.lighting is not None else obj.parent
    poses: dict[int, Path] = {}
    lit: dict[int, list[tuple[int, str, Path]]] = {}
    area: dict[int, Path] = {}
    for f in sorted(obj.iterdir()):
        if m := _POSE.match(f.name):
            poses[int(m.group(1))] = f
        elif m := _AREA.match(f.name):
            area[int(m.group(1))] = f
        elif m := _LIT.match(f.name):
            lit.setdefault(int(m.group(1)), []).append((int(m.group(2)), m.group(3), f))
    orphans = sorted((set(lit) | set(area)) - set(poses))
    if orphans:
        raise InputError(
            f"`{obj}` has images of views {orphans[:5]} without `{{VVV}}_RT.npy`; restore the poses."
        )
    if not lit:
        raise InputError(f"`{obj}` holds no `{{VVV}}_{{LLL}}_{{env}}.png` image.")
    dst.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(dst)
    records: list[FileRecord] = []
    views: list[dict[str, Any]] = []
    names: set[str] = set()
    hdr_folders: set[str] = set()
    first_shape: tuple[int, ...] | None = None

    def add(src: Path, rel: str, kind: str, space: str) -> tuple[int, ...]:
        shape, dtype = png_shape(src)
        _place(src, dst / rel, options.hardlink)
        records.append(
            FileRecord(
                path=rel,
                sha256=sha256_file(dst / rel),
                kind=kind,  # type: ignore[arg-type]
                dtype=dtype,
                shape=shape,
                color_space=space,  # type: ignore[arg-type]
            )
        )
        return shape

    w2c = []
    for row, v in enumerate(sorted(poses)):
        w2c.append(_load_w2c(poses[v]))
        entries = []
        seen: set[int] = set()
        for li, env, src in sorted(lit.get(v, [])):
            if li in seen:
                raise InputError(
                    f"`{obj}` has two images for view {v:03d} lighting {li:03d}; remove one."
                )
            seen.add(li)
            ldr, _ = _lighting_file(obj, lighting, "ldr", src.name)
            hdr, hdr_folder = _lighting_file(obj, lighting, "hdr", src.name)
            if ldr is None or hdr is None:
                raise InputError(
                    f"`{src.name}` of `{obj.name}` has no {'LDR' if ldr is None else 'HDR'} lighting "
                    f"map under `{lighting}/{{LDR,HDR_rescaled,HDR_normalized}}/{obj.name}/`; pass "
                    "the lighting folder with `--lighting`."
                )
            hdr_folders.add(str(hdr_folder))
            stem = f"{v:03d}_{li:03d}"
            shape = add(src, f"lit/{stem}.png", "lit_png", "srgb")
            first_shape = first_shape or shape
            add(ldr, f"envmap_ldr/{stem}.png", "envmap_ldr", "data")
            add(hdr, f"envmap_hdr/{stem}.png", "envmap_hdr", "data")
            names.add(env)
            entries.append(
                {
                    "lighting_index": li,
                    "envmap_name": env,
                    "source_name": src.name,
                    "png": f"lit/{stem}.png",
                    "envmap_ldr": f"envmap_ldr/{stem}.png",
                    "envmap_hdr": f"envmap_hdr/{stem}.png",
                }
            )
        area_rel = None
        if v in area:
            area_rel = f"area/{v:03d}.png"
            add(area[v], area_rel, "area_png", "srgb")
        views.append({"index": v, "row": row, "lit": entries, "area_png": area_rel})
    if len(hdr_folders) > 1:
        raise InputError(f"`{obj}` mixes {sorted(hdr_folders)}; keep one HDR folder per object.")
    if first_shape is None:  # internal: `lit` is never empty here
        raise RuntimeError(f"internal error: no lit image read for `{obj}`")
    height, width = first_shape[0], first_shape[1]
    intrinsics = Intrinsics(
        width=width,
        height=height,
        fx=options.lens_mm / options.sensor_mm * width,
        fy=options.lens_mm / options.sensor_mm * width,
        cx=width / 2.0,
        cy=height / 2.0,
    )
    w2c_arr = np.stack(w2c)  # [V, 3, 4]
    c2w_cv = np.stack([W2CBlender(m).to_c2w_opencv().matrix for m in w2c_arr])  # [V, 4, 4]

    def write_npz(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(fh, w2c_blender=w2c_arr, c2w_opencv=c2w_cv, intrinsics=intrinsics.matrix())

    atomic_write(dst / "cameras.npz", write_npz)
    records.insert(
        0,
        FileRecord(
            path="cameras.npz",
            sha256=sha256_file(dst / "cameras.npz"),
            kind="cameras",
            dtype="npz",
            shape=(),
            color_space="data",
        ),
    )
    manifest = {
        "schema": AUTHORS_OBJECT_SCHEMA,
        "schema_version": AUTHORS_OBJECT_SCHEMA_VERSION,
        "producer": dataclasses.asdict(producer()),
        "created_utc": utc_now(),
        "object_id": obj.name,
        "source": str(obj.resolve()),
        "hdr_folder": hdr_folders.pop(),
        "intrinsics": dataclasses.asdict(intrinsics),
        "views": views,
        "files": [dataclasses.asdict(r) for r in records],
    }
    atomic_write_json(dst / MANIFEST_NAME, manifest)
    return names, sum(len(v["lit"]) for v in views)


def _envmap_names_of(manifest: Path) -> set[str]:
    data = json.loads(manifest.read_text(encoding="utf-8"))
    return {li["envmap_name"] for v in data.get("views", []) for li in v.get("lit", [])}


def convert_authors(
    src: str | Path, out: str | Path, options: ConvertOptions | None = None
) -> ConvertSummary:
    """Convert an authors' split folder into a gaffer artifact (see `gaffer_data.dataset.authors`).

    Args:
        src: the split folder (`<split>/` holding one folder per object).
        out: the destination folder (created; converted objects in it are kept and skipped).
        options: where the lighting maps are, which objects, copy or hard-link.

    Returns:
        What was converted, skipped and why objects failed.

    Raises:
        InputError: `src` holds no object, or a requested object is missing.

    Example:
        >>> from gaffer_data.convert import convert_authors  # doctest: +SKIP
        >>> convert_authors("release/val_unseen", "converted/val_unseen")  # doctest: +SKIP
    """
    options = options or ConvertOptions()
    src, out = Path(src), Path(out)
    objects = find_authors_objects(src, options.object_ids)
    converted, complete, failed = [], [], []
    names: set[str] = set()
    images = 0
    for obj in objects:
        dst = out / OBJECTS_DIR / obj.name
        if (dst / MANIFEST_NAME).is_file():
            complete.append(obj.name)
            names |= _envmap_names_of(dst / MANIFEST_NAME)
            continue
        try:
            obj_names, count = _convert_object(obj, dst, options)
        except (InputError, OSError) as exc:
            logger.warning("%s: not converted: %s", obj.name, exc)
            shutil.rmtree(dst, ignore_errors=True)  # no half-converted folder is left behind
            failed.append(
                FailureRecord(object_id=obj.name, source=str(obj), attempts=1, reason=str(exc))
            )
            continue
        names |= obj_names
        images += count
        converted.append(obj.name)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(
        out / DATASET_NAME,
        {
            "schema": AUTHORS_DATASET_SCHEMA,
            "schema_version": AUTHORS_DATASET_SCHEMA_VERSION,
            "producer": dataclasses.asdict(producer()),
            "created_utc": utc_now(),
            "source": str(src.resolve()),
            "lighting": None if options.lighting is None else str(Path(options.lighting).resolve()),
            "objects": sorted(converted + complete),
            "skipped": [dataclasses.asdict(f) for f in failed],
            "envmap_names": sorted(names),
        },
    )
    return ConvertSummary(
        converted=tuple(converted),
        skipped_complete=tuple(complete),
        failed=tuple(failed),
        images=images,
    )
