"""The embedded default recipe: bundled HDRIs, pymeshlab sample meshes, procedural GLBs (no downloads)."""

import importlib.util
from pathlib import Path

import pytest

from gaffer_data.recipes import (
    build_default_recipe,
    bundled_envmaps,
    object_id_from_path,
    scan_objects,
)
from gaffer_data.render.plan import scan_envmaps


def test_bundled_envmaps_are_the_eight_cc0_hdris() -> None:
    maps = bundled_envmaps()
    assert set(maps) == {
        "city",
        "courtyard",
        "forest",
        "interior",
        "night",
        "studio",
        "sunrise",
        "sunset",
    }
    assert all(p.is_file() for p in maps.values())


def test_object_ids_are_path_safe(tmp_path: Path) -> None:
    assert object_id_from_path(tmp_path / "a b" / "c.glb", tmp_path) == "a_b__c"


@pytest.mark.blender
def test_build_default_recipe(tmp_path: Path) -> None:
    if importlib.util.find_spec("bpy") is None:  # never import it here: pymeshlab may be loaded
        pytest.skip("bpy is not installed (gaffer-data[render])")
    recipe = build_default_recipe(tmp_path, procedural=3, seed=1)
    ids = [oid for oid, _ in scan_objects(recipe.objects)]
    assert [i for i in ids if i.startswith("procedural")] == [
        "procedural__procedural_000",
        "procedural__procedural_001",
        "procedural__procedural_002",
    ]
    assert "cow__cow" in ids and "bunny_textured__bunny10k_textured" in ids
    assert len(scan_envmaps(recipe.envmaps)) == 8
    again = build_default_recipe(tmp_path / "again", procedural=3, seed=1)
    for name in ("procedural_000.glb", "procedural_002.glb"):
        assert (recipe.objects / "procedural" / name).stat().st_size == (
            again.objects / "procedural" / name
        ).stat().st_size


def test_a_failed_procedural_build_leaves_no_partial_objects(tmp_path, monkeypatch):
    # a recipe stopped mid-build left 16 of 400 objects with no marker
    import subprocess

    import gaffer_data.recipes as recipes

    def half_then_fail(cmd, **kwargs):
        out = Path(cmd[cmd.index("--out") + 1])
        out.mkdir(parents=True, exist_ok=True)
        (out / "procedural_000.glb").write_bytes(b"glTF")  # one object written, then a crash
        return subprocess.CompletedProcess(cmd, 1, "", "Blender crashed")

    monkeypatch.setattr(recipes.importlib.util, "find_spec", lambda name: object())
    monkeypatch.setattr(recipes.subprocess, "run", half_then_fail)
    from gaffer_data.errors import InputError

    with pytest.raises(InputError, match="procedural objects failed"):
        recipes.build_default_recipe(tmp_path, procedural=5, sample_meshes_too=False)
    assert not (tmp_path / "objects" / "procedural").exists()
    assert list((tmp_path / "objects").rglob("*.glb")) == []


@pytest.mark.blender
def test_recipe_adds_pybullet_meshes_with_materials_in_disjoint_ranges(tmp_path: Path) -> None:
    if importlib.util.find_spec("bpy") is None or importlib.util.find_spec("pybullet_data") is None:
        pytest.skip("bpy and pybullet are needed (gaffer-data[render,pybullet])")
    recipe = build_default_recipe(
        tmp_path, procedural=0, sample_meshes_too=False, pybullet=2, pybullet_first=500, seed=3
    )
    ids = [oid for oid, _ in scan_objects(recipe.objects)]
    assert ids == ["pybullet__pybullet_500", "pybullet__pybullet_501"]
    glb = (recipe.objects / "pybullet" / "pybullet_500.glb").read_bytes()
    assert glb[:4] == b"glTF" and b"mat_pb_500" in glb  # the random material was exported
    again = build_default_recipe(
        tmp_path / "again",
        procedural=0,
        sample_meshes_too=False,
        pybullet=1,
        pybullet_first=500,
        seed=3,
    )
    assert (again.objects / "pybullet" / "pybullet_500.glb").read_bytes() == glb
