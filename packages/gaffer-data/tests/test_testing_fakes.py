"""`gaffer_data.testing`'s fake-dataset writer writes what the reader reads; `dataset_kind`."""

import json
from pathlib import Path

import numpy as np
import pytest

from gaffer_data.dataset import (
    AUTHORS_DATASET_SCHEMA,
    CameraSample,
    EnvmapRef,
    Intrinsics,
    LitImage,
    ObjectPlan,
    ViewRecord,
    dataset_kind,
    open_dataset,
)
from gaffer_data.errors import IntegrityError
from gaffer_data.testing import tiny_config, write_fake_dataset_json, write_fake_object

pytest.importorskip("PIL")


def _plan(res: int) -> ObjectPlan:
    ref = EnvmapRef(
        name="sky", source="/nowhere/sky.exr", source_sha256="0" * 64, flip=False, yaw_step=0,
        num_steps=4,
    )  # fmt: skip
    lit = LitImage(lighting_index=0, envmap=ref, exr="lit/000_000.png", png="lit/000_000.png")
    view = ViewRecord(
        index=0,
        camera=CameraSample(
            elevation_deg=10.0, azimuth_deg=0.0, distance=2.0, position=(0.0, 0.0, 2.0)
        ),
        lit=(lit,),
        area=None,
        alpha="alpha/000.png",
    )
    return ObjectPlan(
        object_id="thing",
        source="thing.obj",
        views=(view,),
        intrinsics=Intrinsics(width=res, height=res, fx=20.0, fy=20.0, cx=res / 2, cy=res / 2),
        config=tiny_config(views=1, lightings=1, resolution=res),
    )


def _write(root: Path, *, record_files: bool = True) -> Path:
    res = 8
    rgba = np.full((res, res, 4), 200, np.uint8)
    pose = np.hstack([np.eye(3), [[0.0], [0.0], [-2.0]]])
    write_fake_object(
        root / "objects" / "thing",
        _plan(res),
        pngs={"lit/000_000.png": rgba, "alpha/000.png": rgba[..., 3]},
        w2c_blender=pose[None],
        c2w_opencv=np.eye(4)[None],
        intrinsics=np.array([[20.0, 0, 4], [0, 20.0, 4], [0, 0, 1]]),
        record_files=record_files,
    )
    write_fake_dataset_json(root, tiny_config(views=1, lightings=1, resolution=res), ["thing"])
    return root


def test_the_reader_reads_and_verifies_a_fake_dataset(tmp_path: Path) -> None:
    ds = open_dataset(_write(tmp_path))
    assert ds.object_ids == ("thing",) and ds.failures == ()
    (obj,) = ds.iter_objects(verify=True)
    assert [(f.path, f.kind) for f in obj.files] == [
        ("alpha/000.png", "alpha"),
        ("cameras.npz", "cameras"),
        ("lit/000_000.png", "lit_png"),
    ]
    assert obj.poses().w2c_blender.shape == (1, 3, 4)
    (tmp_path / "objects" / "thing" / "lit" / "000_000.png").write_bytes(b"changed")
    with pytest.raises(IntegrityError):
        list(open_dataset(tmp_path).iter_objects(verify=True))


def test_without_records_the_manifest_lists_no_files(tmp_path: Path) -> None:
    (obj,) = open_dataset(_write(tmp_path, record_files=False)).iter_objects(verify=True)
    assert obj.files == ()


def test_dataset_kind(tmp_path: Path) -> None:
    assert dataset_kind(tmp_path) == "render"  # no dataset.json
    assert dataset_kind(_write(tmp_path / "render")) == "render"
    (tmp_path / "authors").mkdir()
    (tmp_path / "authors" / "dataset.json").write_text(
        json.dumps({"schema": AUTHORS_DATASET_SCHEMA})
    )
    assert dataset_kind(tmp_path / "authors") == "authors"
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "dataset.json").write_text("{not json")
    assert dataset_kind(tmp_path / "bad") == "render"
