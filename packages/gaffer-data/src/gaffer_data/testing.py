"""Public test helpers: tiny objects, tiny environment maps, a tiny render config, and fake datasets.

Used by gaffer-data's own tests and by sibling packages and e2e tests (importable under
`--import-mode=importlib`). Nothing here imports bpy.

`write_fake_object` and `write_fake_dataset_json` are the one writer of gaffer-data's on-disk format
without Blender: a caller brings the pixels, the poses and the plan, they write the object folder
(PNGs, `cameras.npz`, `manifest.json`) and the dataset's `dataset.json` through gaffer-data's own
serialisers, so `gaffer_data.open_dataset` reads the result like a real render. Sibling packages' fake
datasets (`gaffer_diffusion.testing.write_tiny_render_dataset`,
`gaffer_diffusion.training.testing.write_synthetic_dataset`) call them.
"""

import dataclasses
import json
import math
import os
import signal
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data.config import AugmentConfig, RenderConfig
from gaffer_data.dataset.manifest import object_manifest_json, producer, sha256_file, utc_now
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    FailureRecord,
    FileRecord,
    Normalization,
    ObjectPlan,
)


def tiny_config(**overrides: object) -> RenderConfig:
    """A render config small enough for CI: 32 px, 4 samples, no denoiser, small importance map."""
    kwargs: dict[str, object] = {
        "views": 2,
        "lightings": 2,
        "resolution": 32,
        "samples": 4,
        "denoise": False,
        "world_map_resolution": 64,
        "threads": 1,
        "augment": AugmentConfig(flip=True, yaw_steps=4),
    }
    kwargs.update(overrides)
    return RenderConfig(**kwargs)  # type: ignore[arg-type]


def hostile_extract_features(object_id: str, path: str | Path, **options: Any) -> Any:
    """`extract_features`, except that ids starting with "hang" sleep for an hour and ids starting
    with "crash" SIGKILL their own process (as the OOM killer would): stand-ins for pathological files
    in tests of the filter's worker isolation (importable, so spawned workers can run it)."""
    if object_id.startswith("hang"):
        time.sleep(3600.0)
    if object_id.startswith("crash"):
        os.kill(os.getpid(), signal.SIGKILL)
    from gaffer_data.filter.features import extract_features

    return extract_features(object_id, path, **options)


def write_exr(path: Path, rgb: np.ndarray) -> Path:
    """Write a `[H, W, 3]` float array as a float32 ZIP-compressed RGB EXR (not atomic: tests only)."""
    import OpenEXR

    rgb = np.asarray(rgb, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    channels = {c: np.ascontiguousarray(rgb[..., i]) for i, c in enumerate("RGB")}
    path.parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))
    return path


def read_exr(path: Path) -> dict[str, np.ndarray]:
    """All channels of an EXR as {name: [H, W] float32} (every part)."""
    import OpenEXR

    out: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, channel in part.channels.items():
                out[name] = np.array(channel.pixels, dtype=np.float32)
    return out


def write_uniform_envmaps(
    folder: Path, colors: dict[str, tuple[float | int, float | int, float | int]], height: int = 8
) -> Path:
    """Write one constant-colour `[height, 2*height]` EXR per {name: linear rgb}; returns `folder`."""
    for name, rgb in colors.items():
        write_exr(
            folder / f"{name}.exr",
            np.broadcast_to(np.asarray(rgb, np.float32), (height, 2 * height, 3)),
        )
    return folder


def write_cube_obj(path: Path, size: float = 1.0) -> Path:
    """An axis-aligned cube OBJ (flat faces) of side `size` centred at the origin."""
    h = size / 2.0
    verts = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    lines = [f"v {x} {y} {z}" for x, y, z in verts] + [f"f {a} {b} {c} {d}" for a, b, c, d in faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_uv_sphere_obj(path: Path, rings: int = 16, segments: int = 32) -> Path:
    """A unit-radius UV sphere OBJ with per-vertex normals (smooth), centred at the origin."""
    verts, faces = [], []
    for i in range(rings + 1):
        theta = math.pi * i / rings
        for j in range(segments):
            phi = 2.0 * math.pi * j / segments
            verts.append(
                (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
            )
    for i in range(rings):
        for j in range(segments):
            a, b = i * segments + j + 1, i * segments + (j + 1) % segments + 1
            c, d = a + segments, b + segments
            faces.append((a, c, d, b))
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in verts]
    lines += [f"vn {x:.7f} {y:.7f} {z:.7f}" for x, y, z in verts]
    lines += ["f " + " ".join(f"{v}//{v}" for v in f) for f in faces]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def write_mirror_sphere_obj(path: Path, rings: int = 64, segments: int = 128) -> Path:
    """A smooth unit UV sphere OBJ with a perfect-mirror material (MTL PBR extension: Pm 1, Pr 0).

    Blender's OBJ importer turns it into a Principled BSDF with metallic 1, roughness 0 and a white
    base colour. The MTL file is written beside the OBJ (`<stem>.mtl`).
    """
    write_uv_sphere_obj(path, rings=rings, segments=segments)
    mtl = path.with_suffix(".mtl")
    mtl.write_text(
        "newmtl mirror\nKd 1 1 1\nKs 1 1 1\nNs 1000\nPm 1.0\nPr 0.0\nillum 3\n", encoding="utf-8"
    )
    body = path.read_text(encoding="utf-8")
    path.write_text(f"mtllib {mtl.name}\nusemtl mirror\n{body}", encoding="utf-8")
    return path


def fake_file_record(folder: Path, path: str) -> FileRecord:
    """The manifest record of a fake dataset's payload `folder/path`, with its sha256.

    The kind is read from the name: `cameras.npz` -> "cameras" (`npz`, data), `alpha/...` -> "alpha"
    (`uint8`, data), `area/...` -> "area_png" and anything else -> "lit_png" (`uint8`, srgb). The shape
    is left empty `()`: fake payloads are not checked against the render resolution.
    """
    if path.endswith(".npz"):
        kind, dtype, space = "cameras", "npz", "data"
    elif "alpha" in path:
        kind, dtype, space = "alpha", "uint8", "data"
    elif path.startswith("area/"):
        kind, dtype, space = "area_png", "uint8", "srgb"
    else:
        kind, dtype, space = "lit_png", "uint8", "srgb"
    return FileRecord(
        path=path,
        sha256=sha256_file(folder / path),
        kind=kind,  # type: ignore[arg-type]
        dtype=dtype,
        shape=(),
        color_space=space,  # type: ignore[arg-type]
    )


def write_fake_object(
    folder: Path,
    plan: ObjectPlan,
    *,
    pngs: Mapping[str, np.ndarray],
    w2c_blender: np.ndarray,
    c2w_opencv: np.ndarray,
    intrinsics: np.ndarray,
    record_files: bool = True,
    source_sha256: str = "0" * 64,
    normalization: Normalization | None = None,
) -> Path:
    """Write one object's folder in gaffer-data's layout without Blender; returns its manifest path.

    Writes each PNG (`gaffer_envmap.writers.write_png` of the array), then `cameras.npz`
    (`w2c_blender`, `c2w_opencv`, `intrinsics`), then `manifest.json` (compact JSON from
    `gaffer_data.dataset.manifest.object_manifest_json`). Not atomic as a set: tests only.

    Args:
        folder: the object's folder, `DATASET/objects/<plan.object_id>` (created).
        plan: the object's plan; its views name the payloads (paths relative to `folder`). Payloads
            the plan names but `pngs` lacks (e.g. the EXRs) are simply not written.
        pngs: `{relative path: uint8 [H, W] (L), [H, W, 3] (RGB) or [H, W, 4] (RGBA)}`, written in
            this order.
        w2c_blender: `[V, 3, 4]` world-to-camera matrices (Blender camera axes).
        c2w_opencv: `[V, 4, 4]` camera-to-world matrices (OpenCV camera axes).
        intrinsics: `[3, 3]` pinhole matrix.
        record_files: list every file written (sorted, with `fake_file_record`) in the manifest's
            `files`, so `verify_object` checks them; False leaves `files` empty.
        source_sha256: the manifest's digest of the (absent) source mesh.
        normalization: the manifest's normalisation (default: scale 1, centre at the origin).

    Returns:
        `folder/manifest.json`.
    """
    from gaffer_envmap.writers import write_png

    folder = Path(folder)
    for rel, pixels in pngs.items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_png(path, np.asarray(pixels, dtype=np.uint8))
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "cameras.npz", "wb") as fh:
        np.savez(fh, w2c_blender=w2c_blender, c2w_opencv=c2w_opencv, intrinsics=intrinsics)
    files: list[FileRecord] = []
    if record_files:
        names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
        files = [fake_file_record(folder, rel) for rel in names if rel != "manifest.json"]
    body = object_manifest_json(
        plan,
        source_sha256=source_sha256,
        normalization=normalization or Normalization(scale=1.0, center=(0.0, 0.0, 0.0)),
        files=files,
    )
    manifest = folder / "manifest.json"
    manifest.write_text(json.dumps(body), encoding="utf-8")
    return manifest


def write_fake_dataset_json(
    root: Path,
    config: RenderConfig,
    object_ids: Sequence[str],
    failures: Sequence[FailureRecord] = (),
) -> Path:
    """Write a dataset's `dataset.json` (`gaffer.render_dataset`) as `gaffer-data render` does.

    Args:
        root: the dataset folder (created).
        config: the render config every object was "rendered" with.
        object_ids: the complete objects, in the order to list them.
        failures: failed objects to record.

    Returns:
        `root/dataset.json` (compact JSON; not atomic: tests only).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    path = root / "dataset.json"
    path.write_text(
        json.dumps(
            {
                "schema": DATASET_SCHEMA,
                "schema_version": DATASET_SCHEMA_VERSION,
                "producer": dataclasses.asdict(producer()),
                "created_utc": utc_now(),
                "config": config.to_dict(),
                "objects": list(object_ids),
                "failures": [dataclasses.asdict(f) for f in failures],
            }
        ),
        encoding="utf-8",
    )
    return path
