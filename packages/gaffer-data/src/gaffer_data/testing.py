"""Public test helpers: tiny objects, tiny environment maps and a tiny render config.

Used by gaffer-data's own tests and by sibling packages and e2e tests (importable under
`--import-mode=importlib`). Nothing here imports bpy.
"""

import math
import os
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data.config import AugmentConfig, RenderConfig


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
    folder: Path, colors: dict[str, tuple[float, float, float]], height: int = 8
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
