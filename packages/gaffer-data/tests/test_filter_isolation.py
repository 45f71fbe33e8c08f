"""The filter under hostile inputs: per-object timeouts, killed workers, memory caps, header face-count
pre-checks."""

import json
import struct
import time
from pathlib import Path

import pytest

pytest.importorskip("trimesh")
pytest.importorskip("pymeshlab")

from gaffer_data.cli import main
from gaffer_data.errors import ConfigError
from gaffer_data.filter import extract_features, filter_objects
from gaffer_data.filter import run as run_mod
from gaffer_data.filter.memory_cap import memory_cap_supported
from gaffer_data.filter.precheck import declared_face_count
from gaffer_data.testing import hostile_extract_features, write_cube_obj, write_uv_sphere_obj


def test_a_hanging_or_killed_object_is_rejected_and_the_run_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    src = tmp_path / "src"
    for name in ("a_cube", "hang_1", "crash_1", "z_cube"):
        write_cube_obj(src / f"{name}.obj")
    # Spawned workers unpickle the extractor by name, so the stand-in runs in them too.
    monkeypatch.setattr(run_mod, "extract_features", hostile_extract_features)
    out = tmp_path / "m.jsonl"
    start = time.monotonic()
    assert main(["filter", str(src), "--out", str(out), "--timeout", "1", "--workers", "2"]) == 0
    elapsed = time.monotonic() - start
    rows = {r["object_id"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert rows["hang_1"]["decision"] == "reject"
    assert rows["hang_1"]["reasons"] == ["timeout after 1 s"]
    assert rows["hang_1"]["features"]["file_size_mb"] > 0
    assert rows["crash_1"]["decision"] == "reject"
    assert rows["crash_1"]["reasons"][0].startswith("feature extraction crashed the process")
    assert rows["a_cube"]["decision"] == rows["z_cube"]["decision"] == "accept"
    assert elapsed < 60.0  # the hour-long sleep was cut short


def test_timeout_must_be_positive(tmp_path: Path) -> None:
    write_cube_obj(tmp_path / "src" / "cube.obj")
    for bad in (-1.0, float("nan")):
        with pytest.raises(ConfigError, match=r"timeout_s.*--timeout"):
            filter_objects(tmp_path / "src", tmp_path / "m.jsonl", timeout_s=bad)
    with pytest.raises(ConfigError, match="workers"):
        filter_objects(tmp_path / "src", tmp_path / "m.jsonl", workers=0)
    assert main(["filter", str(tmp_path / "src"), "--out", "m.jsonl", "--timeout", "-2"]) == 2


@pytest.mark.skipif(not memory_cap_supported(), reason="memory caps need Linux (RLIMIT_AS)")
def test_an_object_over_the_memory_cap_is_rejected_and_the_run_goes_on(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One thread per library in the workers (they inherit this), so thread stacks and per-thread
    # malloc arenas do not eat into the small cap on many-core machines.
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        monkeypatch.setenv(var, "1")
    src = tmp_path / "src"
    write_cube_obj(src / "a_cube.obj")
    # 160k triangles: loading needs ~100 MB more; a cube fits in 16 MB once a worker is warm.
    write_uv_sphere_obj(src / "b_dense.obj", rings=200, segments=400)
    write_cube_obj(src / "c_cube.obj")
    out = tmp_path / "m.jsonl"
    assert main(["filter", str(src), "--out", str(out), "--max-worker-memory-mb", "32"]) == 0
    rows = {r["object_id"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert rows["b_dense"]["decision"] == "reject"
    assert rows["b_dense"]["reasons"] == ["worker exceeded memory cap of 32 MB"]
    assert rows["b_dense"]["features"]["file_size_mb"] > 1.0
    assert rows["a_cube"]["decision"] == rows["c_cube"]["decision"] == "accept"  # a fresh worker
    # Uncapped, the same mesh passes: the cap, not the mesh, rejected it.
    summary = filter_objects(src, out, max_worker_memory_mb=0)
    assert (summary.total, summary.accepted) == (3, 3)


def test_memory_cap_must_be_a_non_negative_integer(tmp_path: Path) -> None:
    write_cube_obj(tmp_path / "src" / "cube.obj")
    for bad in (-1, 1.5, True):
        with pytest.raises(ConfigError, match=r"max_worker_memory_mb.*--max-worker-memory-mb"):
            filter_objects(tmp_path / "src", tmp_path / "m.jsonl", max_worker_memory_mb=bad)  # type: ignore[arg-type]
    argv = ["filter", str(tmp_path / "src"), "--out", "m.jsonl", "--max-worker-memory-mb", "-5"]
    assert main(argv) == 2


def _glb_declaring(path: Path, faces: int) -> Path:
    """A tiny GLB whose JSON declares `faces` triangles it does not hold (a decompression bomb)."""
    doc = {
        "asset": {"version": "2.0"},
        "accessors": [{"count": 3 * faces, "componentType": 5125, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 0}]}],
    }
    body = json.dumps(doc).encode()
    body += b" " * (-len(body) % 4)
    header = struct.pack("<4sII", b"glTF", 2, 20 + len(body))
    path.write_bytes(header + struct.pack("<II", len(body), 0x4E4F534A) + body)
    return path


def test_declared_face_counts_are_read_without_loading(tmp_path: Path) -> None:
    cube = write_cube_obj(tmp_path / "cube.obj")
    assert declared_face_count(cube) == 6  # quads count once: a lower bound
    ply = tmp_path / "bomb.ply"
    ply.write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 900000000\n"
        b"property list uchar int vertex_indices\nend_header\n" + b"\0" * 64
    )
    assert declared_face_count(ply) == 900_000_000
    stl = tmp_path / "two.stl"
    stl.write_bytes(b"\0" * 80 + struct.pack("<I", 2) + b"\0" * 100)
    assert declared_face_count(stl) == 2
    off = tmp_path / "t.off"
    off.write_text("OFF\n# comment\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert declared_face_count(off) == 1
    big_obj = tmp_path / "chunks.obj"
    big_obj.write_bytes(b"f 1 2 3\n" * 300_000)  # 2.4 MB: crosses the 1 MiB read chunks
    assert declared_face_count(big_obj) == 300_000


def test_a_header_bomb_is_rejected_before_loading(tmp_path: Path) -> None:
    glb = _glb_declaring(tmp_path / "bomb.glb", faces=50_000_000)
    assert glb.stat().st_size < 1024
    start = time.monotonic()
    feats = extract_features("bomb", glb, max_faces=2_000_000)
    assert time.monotonic() - start < 5.0
    assert feats.error == "header declares 50000000 faces > max_faces=2000000 (not loaded)"
    assert feats.face_count == 50_000_000
