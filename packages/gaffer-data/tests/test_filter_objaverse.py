"""Filtering an Objaverse-style local cache: uids as ids, annotation metadata, annotation rules (no
downloads: the cache is built here from trimesh primitives and a pymeshlab sample mesh)."""

import gzip
import hashlib
import json
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("trimesh")
pytest.importorskip("pymeshlab")

from gaffer_data.cli import main
from gaffer_data.errors import ConfigError, InputError
from gaffer_data.filter import FilterRules, ObjaverseAnnotation, filter_objects, read_annotations
from gaffer_data.filter.objaverse import find_annotation_files, find_objaverse_glbs
from gaffer_data.recipes import sample_meshes
from gaffer_data.testing import write_cube_obj

NAMES = ("good", "cow", "noncommercial", "weapon", "building", "huge", "animated", "broken")
UID = {n: hashlib.md5(n.encode()).hexdigest() for n in NAMES}  # Objaverse uids are 32 hex digits
RULES = {
    "allowed_licenses": ["cc0", "by", "by-sa"],  # drops non-commercial and no-derivatives
    "excluded_tags": ["weapon"],
    "excluded_categories": ["architecture"],
    "max_annotated_faces": 1_000_000,
    "reject_animated": True,
}


def _annotation(name: str, **fields: Any) -> dict[str, Any]:
    """An entry shaped like `objaverse.load_annotations()` output (extra keys are ignored)."""
    entry: dict[str, Any] = {
        "uid": UID[name],
        "name": name.title(),
        "license": "by",
        "tags": [{"uri": "https://x/t", "slug": "prop", "name": "prop"}],
        "categories": [],
        "faceCount": 12,
        "vertexCount": 8,
        "animationCount": 0,
        "likeCount": 3,
        "viewCount": 40,
        "archives": {"glb": {"size": 1000, "faceCount": 12, "textureCount": 0}},
        "user": {"username": "someone"},
    }
    entry.update(fields)
    return entry


ANNOTATIONS = {
    UID["good"]: _annotation(
        "good",
        tags=[{"name": "chair"}, {"name": "wood"}],
        categories=[{"name": "Furniture & Home"}],
    ),
    UID["noncommercial"]: _annotation("noncommercial", license="by-nc"),
    UID["weapon"]: _annotation("weapon", tags=[{"name": "Weapon"}, {"name": "sword"}]),
    UID["building"]: _annotation("building", categories=[{"name": "Architecture"}]),
    UID["huge"]: _annotation("huge", faceCount=5_000_000, vertexCount=2_600_000),
    UID["animated"]: _annotation("animated", animationCount=2),
}  # no entry for "cow" and "broken"


def _glb(path: Path, mesh: Any) -> None:
    import trimesh

    path.parent.mkdir(parents=True, exist_ok=True)
    data = trimesh.Scene(mesh).export(file_type="glb")
    assert isinstance(data, bytes)
    path.write_bytes(data)


@pytest.fixture()
def cache(tmp_path: Path) -> Path:
    """`<tmp>/objaverse/hf-objaverse-v1/{glbs/<group>/<uid>.glb, metadata/<group>.json.gz}`, as the
    `objaverse` package lays out its cache."""
    import trimesh

    versioned = tmp_path / "objaverse" / "hf-objaverse-v1"
    group = {n: "000-000" if i < 4 else "000-001" for i, n in enumerate(NAMES)}
    box = trimesh.creation.box()
    meshes: dict[str, Any] = {
        "good": box,
        "noncommercial": trimesh.creation.icosphere(subdivisions=2),
        "weapon": trimesh.creation.cylinder(radius=0.1, height=1.0),
        "building": box,
        "animated": box,
    }
    cow = sample_meshes().get("cow")
    meshes["cow"] = trimesh.load(cow[0], force="mesh") if cow else trimesh.creation.capsule()
    for name, mesh in meshes.items():
        _glb(versioned / "glbs" / group[name] / f"{UID[name]}.glb", mesh)
    # Not valid GLBs: loading them would be a "readable" rejection.
    for name in ("huge", "broken"):
        path = versioned / "glbs" / group[name] / f"{UID[name]}.glb"
        path.write_bytes(b"glTF\x02\x00\x00\x00\xff\xff\xff\xff garbage")
    for g in sorted(set(group.values())):
        part = {u: a for u, a in ANNOTATIONS.items() if group[a["name"].lower()] == g}
        (versioned / "metadata").mkdir(parents=True, exist_ok=True)
        (versioned / "metadata" / f"{g}.json.gz").write_bytes(
            gzip.compress(json.dumps(part).encode())
        )
    return tmp_path / "objaverse"


def _rows(out: Path) -> dict[str, dict[str, Any]]:
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    return {r["object_id"]: r for r in rows}


def test_cache_rules_reject_with_reasons_and_metadata_is_recorded(
    cache: Path, tmp_path: Path
) -> None:
    rules = tmp_path / "rules.json"
    rules.write_text(json.dumps(RULES))
    out = tmp_path / "m.jsonl"
    # SRC is the cache root (~/.objaverse), holding hf-objaverse-v1/glbs and metadata/*.json.gz.
    assert main(["filter", str(cache), "--out", str(out), "--rules", str(rules)]) == 0
    rows = _rows(out)
    assert set(rows) == set(UID.values())  # uids are the object ids
    by = {name: rows[UID[name]] for name in NAMES}
    assert {n for n, r in by.items() if r["decision"] == "accept"} == {"good", "cow"}
    assert by["noncommercial"]["reasons"] == [
        "licence 'by-nc' not allowed (allowed: cc0, by, by-sa)"
    ]
    assert by["weapon"]["reasons"] == ["excluded tags: Weapon"]
    assert by["building"]["reasons"] == ["excluded categories: Architecture"]
    assert by["animated"]["reasons"] == ["animated object (2 animations)"]
    # Rejected on its annotation before loading: its garbage file was never opened.
    assert by["huge"]["reasons"] == [
        "annotation declares 5000000 faces > max_annotated_faces=1000000 (not loaded)"
    ]
    assert by["huge"]["features"] is None
    # No annotation: filtered on geometry alone, annotation recorded as null.
    assert by["cow"]["annotation"] is None and by["cow"]["features"]["face_count"] > 1000
    assert by["broken"]["annotation"] is None and by["broken"]["features"]["error"]
    assert by["broken"]["reasons"] and by["broken"]["decision"] == "reject"
    good = by["good"]["annotation"]
    assert good == {
        "uid": UID["good"],
        "name": "Good",
        "license": "by",
        "tags": ["chair", "wood"],
        "categories": ["Furniture & Home"],
        "face_count": 12,
        "vertex_count": 8,
        "animation_count": 0,
        "file_size_bytes": 1000,
        "like_count": 3,
        "view_count": 40,
    }
    assert by["good"]["path"].endswith(f"glbs/000-000/{UID['good']}.glb")
    passed = {o["rule"] for o in by["good"]["rules"] if o["passed"]}
    assert {"allowed_licenses", "excluded_tags", "max_annotated_faces", "readable"} <= passed


def test_single_annotation_files_plain_and_gzipped(cache: Path, tmp_path: Path) -> None:
    versioned = cache / "hf-objaverse-v1"
    (versioned / "annotations.json").write_text(json.dumps({UID["good"]: ANNOTATIONS[UID["good"]]}))
    # annotations.json beside glbs/ wins over the per-group metadata files.
    assert find_annotation_files(versioned) == (versioned / "annotations.json",)
    assert find_annotation_files(tmp_path) == ()
    only = {UID["noncommercial"]: ANNOTATIONS[UID["noncommercial"]]}
    gz = tmp_path / "annotations.json.gz"
    gz.write_bytes(gzip.compress(json.dumps(only).encode()))
    assert set(read_annotations([gz])) == {UID["noncommercial"]}
    # SRC is the glbs/ folder itself; --annotations replaces the cache's own annotations.
    rules = tmp_path / "rules.json"
    rules.write_text(json.dumps({"require_annotation": True}))
    out = tmp_path / "m.jsonl"
    argv = ["filter", str(versioned / "glbs"), "--out", str(out), "--rules", str(rules)]
    assert main([*argv, "--annotations", str(gz)]) == 0
    rows = _rows(out)
    kept = rows[UID["noncommercial"]]
    assert kept["decision"] == "accept" and kept["annotation"]["license"] == "by-nc"
    assert rows[UID["good"]]["reasons"] == ["no annotation entry"]
    assert rows[UID["good"]]["features"] is None  # rejected before loading


def test_malformed_annotation_files_are_named(
    cache: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.json"
    cases: list[tuple[bytes, str]] = [
        (b"{not json", "is not valid JSON"),
        (b"[1, 2]", "holds a JSON list, not an object"),
        (gzip.compress(json.dumps(ANNOTATIONS).encode())[:40], "truncated gzip"),
        (json.dumps({UID["good"]: "by"}).encode(), f"entry '{UID['good']}' is a str"),
        (
            json.dumps({UID["good"]: _annotation("good", tags="chair")}).encode(),
            "`tags` must be a list",
        ),
        (
            json.dumps({UID["good"]: _annotation("good", faceCount=-3)}).encode(),
            "`faceCount`=-3 must be a non-negative integer",
        ),
        (json.dumps({UID["good"]: _annotation("good", license=4)}).encode(), "`license`=4"),
    ]
    for data, message in cases:
        bad.write_bytes(data)
        with pytest.raises(InputError, match="annotations") as info:
            filter_objects(cache, tmp_path / "m.jsonl", annotations_path=bad)
        assert str(bad) in str(info.value) and message in str(info.value), info.value
    missing = ["--annotations", str(tmp_path / "missing.json")]
    assert main(["filter", str(cache), "--out", str(tmp_path / "m.jsonl"), *missing]) == 2
    assert "missing.json" in capsys.readouterr().err
    assert not (tmp_path / "m.jsonl").exists()
    # Entries of objects not in the cache are not parsed (the full annotations hold ~800k).
    bad.write_text(json.dumps({"elsewhere": {"tags": "not a list"}}))
    assert read_annotations([bad], {UID["good"]}) == {}


def test_annotation_rules_are_typed_and_need_annotations(tmp_path: Path, cache: Path) -> None:
    rules = tmp_path / "rules.json"
    for bad, field in (
        ({"allowed_licenses": "by"}, "allowed_licenses"),
        ({"excluded_tags": ["ok", 3]}, "excluded_tags"),
        ({"max_annotated_faces": -1}, "max_annotated_faces"),
        ({"reject_animated": "yes"}, "reject_animated"),
    ):
        rules.write_text(json.dumps(bad))
        with pytest.raises(ConfigError, match=f"rules.*`{field}`"):
            FilterRules.from_json(rules)
    rules.write_text(json.dumps({"allowed_licenses": ["cc0"]}))
    assert FilterRules.from_json(rules).allowed_licenses == ("cc0",)  # stays hashable, frozen
    write_cube_obj(tmp_path / "plain" / "cube.obj")
    with pytest.raises(ConfigError, match="--annotations"):
        filter_objects(tmp_path / "plain", tmp_path / "m.jsonl", rules_path=rules)
    assert find_objaverse_glbs(tmp_path / "plain") is None
    assert find_objaverse_glbs(cache) == cache / "hf-objaverse-v1" / "glbs"


def test_annotation_counts_fall_back_to_the_glb_archive() -> None:
    entry = {"license": "cc0", "archives": {"glb": {"faceCount": 7, "vertexCount": 5, "size": 9}}}
    a = ObjaverseAnnotation.from_entry("u", entry, where="test")
    assert (a.face_count, a.vertex_count, a.file_size_bytes, a.tags) == (7, 5, 9, ())
    rules = FilterRules(allowed_licenses=("CC0",), max_annotated_faces=6)
    outcomes = {o.rule: o for o in rules.evaluate_annotation(a)}
    assert outcomes["allowed_licenses"].passed  # case-insensitive
    assert not outcomes["max_annotated_faces"].passed and outcomes["max_annotated_faces"].value == 7
    assert rules.evaluate_annotation(None) == []  # unannotated: geometry rules only
