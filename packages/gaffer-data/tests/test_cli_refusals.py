"""Nonsense numbers and paths are refused with the argument named."""

import numpy as np
import pytest

from gaffer_data.cli import main


@pytest.mark.parametrize(
    ("argv", "words"),
    [(["recipe", "r", "--procedural", "-1"], "--procedural"), (["recipe", ""], "`out` is empty")],
)
def test_recipe_refuses_nonsense_and_writes_nothing(tmp_path, monkeypatch, capsys, argv, words):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--timeout", "-5"], "`--timeout` is -5.0"),
        (["--timeout", "0"], "`--timeout` is 0.0"),
        (["--resolution", "100000"], "149.0 GiB"),
        (["--resolution", "4"], "`--resolution` is 4"),
        (["--samples", "0"], "`--samples` is 0"),
        (["--workers", "0"], "`--workers` is 0"),
        (["--retries", "-1"], "`--retries` is -1"),
        (["--lightings", "-2"], "`--lightings` is -2"),
        (["--world-map-resolution", "-1"], "`--world-map-resolution`"),
    ],
)
@pytest.mark.parametrize("command", ["render", "render-multiview"])
def test_render_refuses_nonsense_before_scanning(tmp_path, capsys, command, argv, words):
    # the folders do not even exist: the numbers are checked first, and nothing is created
    out = tmp_path / "out"
    base = [command, "--objects", str(tmp_path / "no"), "--envmaps", str(tmp_path / "no")]
    assert main([*base, "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not out.exists()


def test_recipe_refuses_an_absurd_procedural_count(tmp_path, capsys):
    assert main(["recipe", str(tmp_path / "r"), "--procedural", "100000"]) == 2
    assert "0..10000" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        (["--pybullet", "1001"], "`--pybullet` is 1001"),
        (["--pybullet", "10", "--pybullet-first", "995"], "`--pybullet-first` is 995"),
    ],
)
def test_recipe_refuses_pybullet_ranges_past_the_shipped_meshes(tmp_path, capsys, flags, words):
    assert main(["recipe", str(tmp_path / "r"), "--procedural", "0", *flags]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not (tmp_path / "r").exists()


def test_info_refuses_a_folder_that_is_no_dataset(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("not a dataset")
    assert main(["info", str(tmp_path)]) == 2
    assert "is not a gaffer-data dataset" in capsys.readouterr().err


def test_info_names_object_folders_without_a_manifest_and_verify_fails(tmp_path, capsys):
    # a deleted (or never written) manifest.json is reported, and --verify does not say yes
    (tmp_path / "objects" / "mug" / "lit").mkdir(parents=True)
    (tmp_path / "objects" / "mug" / "lit" / "000_000.png").write_bytes(b"")
    assert main(["info", str(tmp_path)]) == 0
    assert "1 object folder(s) without manifest.json (incomplete): mug" in capsys.readouterr().out
    assert main(["info", str(tmp_path), "--verify"]) == 1
    assert "--verify" in capsys.readouterr().err


def _pool_and_objects(tmp_path, maps):
    """An objects folder with one (never rendered) mesh and an env-map folder holding `maps`."""
    from gaffer_envmap.io_exr import write_exr

    objects, envmaps = tmp_path / "objects", tmp_path / "envmaps"
    objects.mkdir()
    (objects / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    envmaps.mkdir()
    for name, (h, w) in maps.items():
        write_exr(envmaps / f"{name}.exr", np.ones((h, w, 3), np.float32))
    return objects, envmaps


@pytest.mark.parametrize("command", ["render", "render-multiview"])
def test_render_refuses_a_map_that_is_not_2_to_1_before_creating_the_output(
    tmp_path, capsys, command
):
    objects, envmaps = _pool_and_objects(tmp_path, {"ok": (16, 32), "wide": (16, 48)})
    out = tmp_path / "out"
    argv = [command, "--objects", str(objects), "--envmaps", str(envmaps), "--out", str(out)]
    assert main([*argv, "--yaw-steps", "4"]) == 2
    err = capsys.readouterr().err
    assert "`wide.exr` is 48 x 16 (3:1), not a 2:1 lat-long map" in err and "32 x 16" in err
    assert err.count("\n") == 1 and not out.exists()


@pytest.mark.parametrize("command", ["render", "render-multiview"])
def test_render_refuses_yaw_steps_that_do_not_divide_the_width(tmp_path, capsys, command):
    objects, envmaps = _pool_and_objects(tmp_path, {"a": (16, 32), "b": (24, 48)})
    out = tmp_path / "out"
    argv = [command, "--objects", str(objects), "--envmaps", str(envmaps), "--out", str(out)]
    assert main([*argv, "--yaw-steps", "7"]) == 2
    err = capsys.readouterr().err
    assert "`--yaw-steps` (`augment.yaw_steps`) is 7" in err and "width 32 of `a.exr`" in err
    assert "(and 1 more)" in err and "[1, 2, 4, 8, 16]" in err  # gcd(32, 48) = 16
    assert err.count("\n") == 1 and not out.exists()


def test_pool_check_passes_good_maps_and_reads_radiance_headers(tmp_path):
    from gaffer_data.errors import InputError
    from gaffer_data.render.plan import PoolEntry, check_pool_maps, envmap_size
    from gaffer_envmap.bundled import bundled_hdris

    pool = [PoolEntry(name=k, path=p, sha256="") for k, p in bundled_hdris().items()]
    check_pool_maps(pool, 8)  # the shipped 1024 x 512 maps: 2:1 and 8 divides 1024
    hdr = tmp_path / "x.hdr"
    hdr.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 64 +X 128\n" + bytes(16))
    assert envmap_size(hdr) == (128, 64)
    garbage = tmp_path / "g.exr"
    garbage.write_bytes(b"not an image at all")
    with pytest.raises(InputError, match="no readable EXR or Radiance header"):
        envmap_size(garbage)


def _output_fixtures(tmp_path):
    """A file where a folder is expected, a folder where a file is, and output folders whose
    slots (a file the command writes, or a sub-folder) hold the wrong kind."""
    (tmp_path / "afile").write_text("a file where a folder is expected")
    (tmp_path / "adir").mkdir()
    (tmp_path / "rec").mkdir()
    (tmp_path / "rec" / "objects").write_text("a file where objects/ goes")
    (tmp_path / "rec2" / "envmaps" / "city.exr").mkdir(parents=True)
    (tmp_path / "ds" / "dataset.json").mkdir(parents=True)
    (tmp_path / "sch" / "gaffer.rendered_object-9.schema.json").mkdir(parents=True)
    (tmp_path / "clf" / "classifier.json").mkdir(parents=True)


_NO = "{T}/no"  # a folder that does not exist: the output is checked before any scan
OUTPUT_CASES = [
    ("recipe {T}/afile --procedural 0", "`out` {T}/afile is a file"),
    ("recipe {T}/afile/r --procedural 0", "`out`"),
    ("recipe {T}/rec --procedural 0", "objects is a file"),
    ("recipe {T}/rec2 --procedural 0", "city.exr is a folder"),
    ("recipe {T}/r --procedural 0 --seed -1", "`--seed` is -1"),
    (f"render --objects {_NO} --envmaps {_NO} --out {{T}}/afile", "`--out` {T}/afile is a file"),
    (f"render --objects {_NO} --envmaps {_NO} --out {{T}}/ds", "dataset.json is a folder"),
    (f"render --objects {_NO} --envmaps {_NO} --out {{T}}/r --seed -1", "`--seed` is -1"),
    (f"render-multiview --objects {_NO} --envmaps {_NO} --out {{T}}/afile", "`--out`"),
    (f"render-multiview --objects {_NO} --envmaps {_NO} --out {{T}}/r --seed -2", "`--seed`"),
    ("schema --out {T}/afile", "`--out` {T}/afile is a file"),
    ("schema --out {T}/sch", "schema.json is a folder"),
    (f"filter {_NO} --out {{T}}/adir", "`--out` {T}/adir is a folder"),
    (f"train-classifier {_NO} {_NO} --out {{T}}/afile", "`--out`"),
    (f"train-classifier {_NO} {_NO} --out {{T}}/clf", "classifier.json is a folder"),
    (f"convert-authors {_NO} --out {{T}}/afile", "`--out`"),
]


@pytest.mark.parametrize(("argv", "words"), OUTPUT_CASES)
def test_bad_output_paths_are_refused_before_any_work(tmp_path, capsys, argv, words):
    _output_fixtures(tmp_path)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert main([a.replace("{T}", str(tmp_path)) for a in argv.split()]) == 2
    err = capsys.readouterr().err
    assert words.replace("{T}", str(tmp_path)) in err and err.count("\n") == 1, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


@pytest.mark.parametrize(
    ("flags", "missing", "words"),
    [
        (["--procedural", "2"], "bpy", "gaffer-data[render]"),
        (["--procedural", "0", "--pybullet", "2"], "pybullet_data", "pip install pybullet"),
    ],
)
def test_recipe_without_its_builder_writes_nothing(
    tmp_path, monkeypatch, capsys, flags, missing, words
):
    """A missing writer of the procedural objects (bpy, pybullet) is refused before the bundled
    maps and sample meshes are copied (it used to leave a half-written recipe)."""
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == missing else real(n, *a)
    )
    assert main(["recipe", str(tmp_path / "r"), *flags]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "r").exists()
