"""Nonsense numbers and paths are refused with the argument named (issue 17)."""

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
