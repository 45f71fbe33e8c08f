"""The pure reader: manifests written by the runner's writer, version rules, integrity (no bpy)."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from gaffer_data._atomic import atomic_write_json
from gaffer_data.dataset import OBJECT_SCHEMA_VERSION, open_dataset, read_object
from gaffer_data.dataset.schema import ObjectPlan
from gaffer_data.errors import (
    GafferSchemaWarning,
    IntegrityError,
    ManifestError,
    SchemaVersionError,
)
from gaffer_data.render.plan import PoolEntry, plan_object
from gaffer_data.render.runner import _dataset_json, _finish_object, _prepare_folder
from gaffer_data.render.worker import NORMALIZATION_NAME
from gaffer_data.testing import tiny_config


def _fake_object(out: Path, object_id: str = "obj") -> ObjectPlan:
    """Write a complete object as the worker would, with placeholder payloads."""
    pool = [PoolEntry(name="a", path=Path("/x/a.exr"), sha256="1" * 64)]
    cfg = tiny_config()
    plan = plan_object(object_id, "/x/obj.glb", pool, cfg)
    root = out / "objects" / object_id
    _prepare_folder(plan, root)
    for view in plan.views:
        paths = [p for li in view.lit for p in (li.exr, li.png)] + [view.alpha]
        if view.area is not None:
            a = view.area
            paths += [a.exr, a.png, a.normal, a.albedo, a.depth]
        for p in paths:
            (root / p).parent.mkdir(parents=True, exist_ok=True)
            (root / p).write_bytes(p.encode())
    atomic_write_json(root / NORMALIZATION_NAME, {"scale": 0.5, "center": [0.0, 1.0, 2.0]})
    _finish_object(plan, root, "2" * 64)
    _dataset_json(out, cfg, [])
    return plan


def test_round_trip(tmp_path: Path) -> None:
    plan = _fake_object(tmp_path)
    obj = read_object(tmp_path / "objects" / "obj", verify=True)
    assert obj.object_id == "obj" and obj.views == plan.views and obj.config == plan.config
    assert obj.normalization.scale == 0.5 and obj.normalization.center == (0.0, 1.0, 2.0)
    assert obj.producer.package == "gaffer-data" and obj.schema_version == OBJECT_SCHEMA_VERSION
    kinds = {f.kind for f in obj.files}
    assert kinds == {
        "cameras",
        "lit_exr",
        "lit_png",
        "area_exr",
        "area_png",
        "normal",
        "albedo",
        "depth",
        "alpha",
    }
    assert not (tmp_path / "objects" / "obj" / "_plan.json").exists()
    poses = obj.poses()
    assert poses.w2c_blender.shape == (2, 3, 4) and not poses.w2c_blender.flags.writeable


def test_dataset_samples(tmp_path: Path) -> None:
    _fake_object(tmp_path, "a")
    _fake_object(tmp_path, "b")
    ds = open_dataset(tmp_path)
    assert ds.object_ids == ("a", "b") and ds.config == tiny_config() and ds.failures == ()
    samples = list(ds.iter_samples())
    assert len(samples) == 2 * 2 * 2
    s = samples[0]
    assert s.image_exr.suffix == ".exr" and s.envmap.name == "a" and s.c2w_opencv.shape == (4, 4)
    rotation, translation = s.w2c_blender[:, :3], s.w2c_blender[:, 3]
    np.testing.assert_allclose(-rotation.T @ translation, s.c2w_opencv[:3, 3], atol=1e-9)


def test_incomplete_objects_are_not_listed(tmp_path: Path) -> None:
    _fake_object(tmp_path, "done")
    (tmp_path / "objects" / "half").mkdir()
    assert open_dataset(tmp_path).object_ids == ("done",)


def test_verify_detects_corruption(tmp_path: Path) -> None:
    _fake_object(tmp_path)
    root = tmp_path / "objects" / "obj"
    (root / "lit" / "000_000.exr").write_bytes(b"truncated")
    read_object(root)  # without verify, only the manifest is read
    with pytest.raises(IntegrityError, match=r"000_000\.exr"):
        read_object(root, verify=True)
    (root / "lit" / "000_000.exr").unlink()
    with pytest.raises(IntegrityError, match="missing"):
        read_object(root, verify=True)


def _rewrite_version(root: Path, version: str) -> None:
    path = root / "manifest.json"
    data = json.loads(path.read_text())
    data["schema_version"] = version
    data["a_field_from_the_future"] = {"x": 1}
    path.write_text(json.dumps(data))


def test_major_version_mismatch_raises(tmp_path: Path) -> None:
    _fake_object(tmp_path)
    root = tmp_path / "objects" / "obj"
    _rewrite_version(root, "2.0")
    with pytest.raises(SchemaVersionError, match="MAJOR") as info:
        read_object(root)
    assert isinstance(info.value, ValueError)


def test_newer_minor_version_warns(tmp_path: Path) -> None:
    _fake_object(tmp_path)
    root = tmp_path / "objects" / "obj"
    _rewrite_version(root, "1.7")
    with pytest.warns(GafferSchemaWarning, match="newer"):
        obj = read_object(root)
    assert obj.schema_version == "1.7"


def test_older_minor_is_silent(tmp_path: Path) -> None:
    _fake_object(tmp_path)
    root = tmp_path / "objects" / "obj"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_object(root)


@pytest.mark.parametrize(
    "content, match",
    [
        ("not json", "not readable JSON"),
        ("[]", "JSON list"),
        ('{"schema": "other", "schema_version": "1.0"}', "schema"),
    ],
)
def test_bad_manifests(tmp_path: Path, content: str, match: str) -> None:
    (tmp_path / "manifest.json").write_text(content)
    with pytest.raises((ManifestError, SchemaVersionError), match=match):
        read_object(tmp_path)


def test_missing_manifest(tmp_path: Path) -> None:
    with pytest.raises(ManifestError, match="does not exist"):
        read_object(tmp_path)


def test_reader_does_not_import_bpy() -> None:
    import subprocess
    import sys

    code = "import sys, gaffer_data, gaffer_data.dataset; assert 'bpy' not in sys.modules and 'pymeshlab' not in sys.modules"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_stale_temporaries_of_a_killed_writer_are_removed(tmp_path: Path) -> None:
    import subprocess
    import sys

    from gaffer_data._atomic import is_stale_temporary, remove_stale_temporaries

    (tmp_path / "lit").mkdir()
    # A writer killed inside gaffer_envmap.atomic_path leaves its temporary behind.
    code = (
        "import os, sys; from gaffer_envmap.atomic import atomic_path\n"
        "with atomic_path(sys.argv[1]) as tmp:\n    tmp.write_text('half'); os._exit(0)\n"
    )
    subprocess.run([sys.executable, "-c", code, str(tmp_path / "lit" / "000_000.exr")], check=True)
    (tmp_path / "lit" / "000_001.exr").write_text("done")
    (tmp_path / ".hidden.json").write_text("{}")
    left = [p for p in tmp_path.rglob("*") if p.is_file() and is_stale_temporary(p)]
    assert len(left) == 1 and left[0].suffix == ".exr"
    assert remove_stale_temporaries(tmp_path) == 1
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == [
        ".hidden.json",
        "000_001.exr",
    ]
    assert remove_stale_temporaries(tmp_path / "missing") == 0
