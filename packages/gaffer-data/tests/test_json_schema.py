"""JSON Schemas of manifest.json / dataset.json (rendered and converted) validate what the code really
writes (jsonschema)."""

import copy
import dataclasses
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("jsonschema")  # a dependency of ray (the `ray` and `all` extras)

import jsonschema

from gaffer_data.cli import main
from gaffer_data.config import MultiviewConfig, multiview_render_config
from gaffer_data.convert import convert_authors
from gaffer_data.dataset.authors import (
    AUTHORS_DATASET_SCHEMA,
    AUTHORS_DATASET_SCHEMA_VERSION,
    AUTHORS_OBJECT_SCHEMA,
    AUTHORS_OBJECT_SCHEMA_VERSION,
    AuthorsLitImage,
    AuthorsView,
)
from gaffer_data.dataset.json_schema import (
    authors_dataset_manifest_schema,
    authors_object_manifest_schema,
    dataset_manifest_schema,
    object_manifest_schema,
    schema_filename,
)
from gaffer_data.dataset.manifest import object_manifest_json
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    OBJECT_SCHEMA,
    OBJECT_SCHEMA_VERSION,
    FileRecord,
    Normalization,
    ViewRecord,
)
from gaffer_data.render.plan import PoolEntry, plan_for
from gaffer_data.testing import tiny_config, write_cube_obj, write_uniform_envmaps
from gaffer_envmap.poses import orbit_w2c_blender


def _errors(schema: dict, doc: dict) -> list[str]:
    validator = jsonschema.Draft202012Validator(schema)
    return [e.message for e in validator.iter_errors(doc)]


def test_cli_writes_valid_versioned_schemas(tmp_path: Path) -> None:
    assert main(["schema", "--out", str(tmp_path / "schemas")]) == 0
    assert len(list((tmp_path / "schemas").iterdir())) == 4
    for schema, version in (
        (OBJECT_SCHEMA, OBJECT_SCHEMA_VERSION),
        (DATASET_SCHEMA, DATASET_SCHEMA_VERSION),
        (AUTHORS_OBJECT_SCHEMA, AUTHORS_OBJECT_SCHEMA_VERSION),
        (AUTHORS_DATASET_SCHEMA, AUTHORS_DATASET_SCHEMA_VERSION),
    ):
        doc = json.loads((tmp_path / "schemas" / schema_filename(schema, version)).read_text())
        jsonschema.Draft202012Validator.check_schema(doc)
        assert doc["x-gaffer-schema"] == schema and doc["x-gaffer-schema-version"] == version
    # Generated from the dataclasses: every field is described.
    defs = object_manifest_schema()["$defs"]
    for cls in (ViewRecord, FileRecord, Normalization):
        assert set(defs[cls.__name__]["properties"]) == {f.name for f in dataclasses.fields(cls)}
    defs = authors_object_manifest_schema()["$defs"]
    for cls in (AuthorsView, AuthorsLitImage, FileRecord):
        assert set(defs[cls.__name__]["properties"]) == {f.name for f in dataclasses.fields(cls)}


def _png(path: Path, value: int, size: int) -> None:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((size, size, 3), value, np.uint8), mode="RGB").save(path)


def test_converted_authors_manifests_validate_and_defects_do_not(tmp_path: Path) -> None:
    # A release split with object "a" (two views, two lightings, maps inside the object folder) and
    # "c", whose image lacks its lighting maps, so dataset.json records a skipped object too.
    split = tmp_path / "val_unseen"
    for name in ("a", "c"):
        for v in range(2):
            (split / name).mkdir(parents=True, exist_ok=True)
            np.save(split / name / f"{v:03d}_RT.npy", orbit_w2c_blender(90.0 * v, 20.0, 2.0).matrix)
            _png(split / name / f"random_lighting_{v:03d}.png", 200, 8)
            for li, env in enumerate(("cannon_2k_225", "sky_1k_000")):
                image = f"{v:03d}_{li:03d}_{env}.png"
                _png(split / name / image, 10 * v + li, 8)
                if name == "a":
                    _png(split / name / "LDR" / image, 100, 16)
                    _png(split / name / "HDR_rescaled" / image, 150, 16)
    out = tmp_path / "converted"
    summary = convert_authors(split, out)
    assert summary.converted == ("a",) and [f.object_id for f in summary.failed] == ["c"]
    manifest = json.loads((out / "objects" / "a" / "manifest.json").read_text())
    dataset = json.loads((out / "dataset.json").read_text())
    schema = authors_object_manifest_schema()
    assert _errors(schema, manifest) == []
    assert _errors(authors_dataset_manifest_schema(), dataset) == []
    assert dataset["skipped"][0]["object_id"] == "c"
    bad = copy.deepcopy(manifest)
    bad["hdr_folder"] = "HDR_raw"
    bad["views"][0]["lit"][0]["lighting_index"] = "000"
    bad["views"][1]["area_png"] = 3
    bad["files"][0]["sha256"] = "not-a-digest"
    del bad["intrinsics"]["fx"]
    bad["schema_version"] = "2.0"
    assert len(_errors(schema, bad)) == 6
    # Neither confusable with the rendered manifests nor with each other.
    assert _errors(object_manifest_schema(), manifest) != []
    assert _errors(schema, dataset) != []


def test_a_multiview_manifest_body_validates_and_defects_do_not() -> None:
    config = multiview_render_config(MultiviewConfig(train_views=3, test_views=1), resolution=32)
    pool = [PoolEntry(name="m", path=Path("/x/m.exr"), sha256="ab" * 32)]
    plan = plan_for("obj", "/x/obj.glb", pool, config)
    record = FileRecord(
        path="cameras.npz",
        sha256="0" * 64,
        kind="cameras",
        dtype="npz",
        shape=(),
        color_space="data",
    )
    body = json.loads(
        json.dumps(
            object_manifest_json(
                plan,
                source_sha256="f" * 64,
                normalization=Normalization(scale=1.0, center=(0.0, 0.0, 0.0)),
                files=[record],
            )
        )
    )
    schema = object_manifest_schema()
    assert _errors(schema, body) == []
    assert {v["split"] for v in body["views"]} == {"train", "test"}
    bad = copy.deepcopy(body)
    bad["schema"] = "gaffer.something_else"
    bad["views"][0]["lit"][0]["envmap"]["flip"] = "yes"
    bad["files"][0]["kind"] = "movie"
    bad["normalization"]["center"] = [0.0, 0.0]
    del bad["intrinsics"]
    bad["schema_version"] = "2.0"
    assert len(_errors(schema, bad)) == 6
    older = copy.deepcopy(body)  # a 1.0 manifest: no split, unknown extras from a newer MINOR pass
    older["schema_version"] = "1.0"
    for view in older["views"]:
        del view["split"]
    older["extra_field_of_1_9"] = {"anything": 1}
    assert _errors(schema, older) == []


@pytest.mark.blender
def test_a_real_render_validates(tmp_path: Path) -> None:
    if importlib.util.find_spec("bpy") is None:  # never import it here: pymeshlab may be loaded
        pytest.skip("bpy is not installed (gaffer-data[render])")
    from gaffer_data.recipes import scan_objects
    from gaffer_data.render.plan import scan_envmaps
    from gaffer_data.render.runner import RunOptions, render_dataset

    write_cube_obj(tmp_path / "objects" / "cube.obj")
    (tmp_path / "objects" / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    write_uniform_envmaps(tmp_path / "envmaps", {"red": (1.0, 0.1, 0.1)})
    out = tmp_path / "render"
    summary = render_dataset(
        scan_objects(tmp_path / "objects"),
        scan_envmaps(tmp_path / "envmaps"),
        out,
        tiny_config(views=1, lightings=1),
        RunOptions(workers=1, retries=0, progress=False),
    )
    assert summary.rendered == ("cube",) and len(summary.failed) == 1
    manifest = json.loads((out / "objects" / "cube" / "manifest.json").read_text())
    dataset = json.loads((out / "dataset.json").read_text())
    assert _errors(object_manifest_schema(), manifest) == []
    assert _errors(dataset_manifest_schema(), dataset) == []
    assert dataset["failures"][0]["object_id"] == "broken"
    assert _errors(object_manifest_schema(), dataset) != []  # the two schemas are not confusable
