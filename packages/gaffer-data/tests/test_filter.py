"""Filtering: features, rules with reasons, hostile files, the classifier and the CLI (no bpy)."""

import json
from pathlib import Path

import pytest

pytest.importorskip("trimesh")
pytest.importorskip("pymeshlab")
pytest.importorskip("sklearn")

from gaffer_data.cli import main
from gaffer_data.errors import ConfigError, InputError
from gaffer_data.filter import FilterRules, QualityClassifier, extract_features, train_classifier
from gaffer_data.testing import write_cube_obj, write_uv_sphere_obj


def _glb(path: Path, material: dict) -> Path:
    import trimesh

    scene = trimesh.Scene(trimesh.creation.box())
    data = scene.export(file_type="glb")
    # Rewrite the JSON chunk with the material we want (same length padding is not needed: rebuild).
    import struct

    json_len = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20 : 20 + json_len])
    doc["materials"] = [material]
    for mesh in doc["meshes"]:
        for prim in mesh["primitives"]:
            prim["material"] = 0
    body = json.dumps(doc).encode()
    body += b" " * (-len(body) % 4)
    rest = data[20 + json_len :]
    out = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(body) + len(rest))
    out += struct.pack("<II", len(body), 0x4E4F534A) + body + rest
    path.write_bytes(out)
    return path


@pytest.fixture()
def objects(tmp_path: Path) -> Path:
    src = tmp_path / "src"
    write_cube_obj(src / "cube.obj")
    write_uv_sphere_obj(src / "sphere.obj")
    (src / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00\xff\xff\xff\xff garbage")
    (src / "empty.obj").write_text("# nothing\n")
    (src / "flat.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nv 3 0 0\nf 1 2 3\nf 2 3 4\n")
    (src / "nan.obj").write_text(
        "v nan 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 2 3 4\nf 1 3 4\n"
    )
    _glb(
        src / "glass.glb",
        {
            "pbrMetallicRoughness": {"metallicFactor": 0.0},
            "extensions": {"KHR_materials_transmission": {"transmissionFactor": 1.0}},
        },
    )
    _glb(
        src / "metal.glb",
        {
            "pbrMetallicRoughness": {
                "baseColorFactor": [0.9, 0.8, 0.2, 1.0],
                "metallicFactor": 1.0,
                "roughnessFactor": 0.2,
            }
        },
    )
    return src


def test_features_of_good_meshes(objects: Path) -> None:
    cube = extract_features("cube", objects / "cube.obj")
    assert cube.error is None and cube.face_count == 12 and cube.connected_components == 1
    assert cube.aspect_ratio == pytest.approx(1.0) and cube.surface_area == pytest.approx(6.0)
    metal = extract_features("metal", objects / "metal.glb")
    assert (
        metal.metallic == 1.0
        and metal.roughness == pytest.approx(0.2)
        and metal.material_count >= 1
    )
    assert metal.vector().shape == (19,)


def test_filter_cli_records_every_object_with_reasons(objects: Path, tmp_path: Path) -> None:
    out = tmp_path / "manifest.jsonl"
    assert main(["filter", str(objects), "--out", str(out)]) == 0
    rows = {r["object_id"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert set(rows) == {"cube", "sphere", "broken", "empty", "flat", "nan", "glass", "metal"}
    accepted = {k for k, r in rows.items() if r["decision"] == "accept"}
    assert accepted == {"cube", "sphere", "metal"}
    assert any("transparent" in reason for reason in rows["glass"]["reasons"])
    assert rows["broken"]["features"]["error"] and rows["empty"]["reasons"]
    assert any("zero surface area" in r or "thin" in r for r in rows["flat"]["reasons"])
    assert any("non-finite" in r for r in rows["nan"]["reasons"])
    assert all(r["reasons"] == [] for k, r in rows.items() if k in accepted)


def test_rules_from_json(tmp_path: Path, objects: Path) -> None:
    path = tmp_path / "rules.json"
    path.write_text(json.dumps({"max_transmission": 1.0, "min_faces": 100}))
    rules = FilterRules.from_json(path)
    assert rules.max_transmission == 1.0
    outcomes = rules.evaluate(extract_features("cube", objects / "cube.obj"))
    assert [o.rule for o in outcomes if not o.passed] == ["min_faces"]
    path.write_text(json.dumps({"max_trasmission": 1.0}))
    with pytest.raises(ConfigError, match="unknown fields"):
        FilterRules.from_json(path)


def test_huge_files_are_not_loaded(objects: Path) -> None:
    feats = extract_features("sphere", objects / "sphere.obj", max_file_mb=1e-6)
    assert feats.error is not None and "max_file_mb" in feats.error and feats.face_count == 0


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_classifier_trains_scores_and_reloads(tmp_path: Path) -> None:
    src = tmp_path / "src"
    for i in range(8):
        write_uv_sphere_obj(src / f"good_{i}.obj", rings=8 + i, segments=12 + 2 * i)
        write_cube_obj(src / f"bad_{i}.obj", size=0.5 + 0.1 * i)
    manifest = tmp_path / "m.jsonl"
    assert main(["filter", str(src), "--out", str(manifest)]) == 0
    labels = tmp_path / "labels.csv"
    labels.write_text("object_id,label\n" + "".join(f"good_{i},1\nbad_{i},0\n" for i in range(8)))
    report = train_classifier(manifest, labels, tmp_path / "clf", folds=4)
    assert report.samples == 16 and report.positives == 8 and report.cv_accuracy_mean >= 0.9
    meta = json.loads((tmp_path / "clf" / "classifier.json").read_text())
    assert (
        meta["schema"] == "gaffer.quality_classifier"
        and meta["report"]["cv_accuracy_mean"] == report.cv_accuracy_mean
    )
    clf = QualityClassifier.load(tmp_path / "clf")
    out = tmp_path / "scored.jsonl"
    assert main(["filter", str(src), "--out", str(out), "--classifier", str(tmp_path / "clf")]) == 0
    rows = {r["object_id"]: r for r in map(json.loads, out.read_text().splitlines())}
    assert all(
        rows[f"good_{i}"]["score"] > 0.5 and rows[f"bad_{i}"]["decision"] == "reject"
        for i in range(8)
    )
    assert clf.report == report
    (tmp_path / "clf" / "model.pkl").write_bytes(b"tampered")
    with pytest.raises(Exception, match="sha256"):
        QualityClassifier.load(tmp_path / "clf")


def test_classifier_needs_enough_labels(tmp_path: Path, objects: Path) -> None:
    manifest = tmp_path / "m.jsonl"
    main(["filter", str(objects), "--out", str(manifest)])
    labels = tmp_path / "labels.csv"
    labels.write_text("object_id,label\ncube,1\nsphere,0\n")
    with pytest.raises(InputError, match="folds"):
        train_classifier(manifest, labels, tmp_path / "clf", folds=5)
    labels.write_text("id,quality\n")
    with pytest.raises(InputError, match="object_id,label"):
        train_classifier(manifest, labels, tmp_path / "clf")


@pytest.mark.parametrize("missing", ["trimesh", "pymeshlab"])
def test_filter_without_the_mesh_libraries_refuses_in_one_line(
    objects: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys, missing: str
) -> None:
    """Without trimesh every object was rejected "not installed" and the run exited 0."""
    import builtins

    real_import = builtins.__import__

    def no_module(name, *args, **kwargs):
        if name == missing or name.startswith(missing + "."):
            raise ImportError(f"No module named {missing!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_module)
    out = tmp_path / "manifest.jsonl"
    assert main(["filter", str(objects), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"`{missing}` is not installed" in err and "gaffer-data[filter]" in err
    assert not out.exists()  # refused before any object was loaded or a line written
