"""Nonsense numbers and paths are refused with the argument named."""

import os

import numpy as np
import pytest

from gaffer_envmap.cli import main
from gaffer_envmap.io import write_png


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["rotate", "a.exr", "b.exr", "--w2c", "p.npy", "--spin", "nan"], "finite"),
        (["encode", "a.exr", "--w2c", "p.npy", "--out-dir", "o", "--spin", "inf"], "finite"),
        (["augment", "a.exr", "--out-dir", "o", "--yaw-steps", "0"], "integer >= 1"),
        (["rotate", "a.exr", "b.exr", "--w2c", "p.npy", "--supersample", "0"], "integer >= 1"),
    ],
)
def test_nonsense_numbers_are_refused_by_the_parser(capsys, argv, words) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert words in capsys.readouterr().err


def _inputs(tmp_path):
    """A small map, a camera, a file where a folder is expected and a folder where a file is."""
    import numpy as np

    from gaffer_envmap.environment_map import EnvironmentMap
    from gaffer_envmap.io import write_envmap

    src = tmp_path / "in" / "sky.exr"
    src.parent.mkdir()
    write_envmap(src, EnvironmentMap(radiance_linear=np.full((8, 16, 3), 0.5, np.float32)))
    w2c = tmp_path / "in" / "w2c.npy"
    np.save(w2c, np.concatenate([np.eye(3), [[0.0], [0.0], [-2.0]]], axis=1))
    (tmp_path / "afile").write_text("a file where a folder is expected")
    (tmp_path / "adir").mkdir()
    return str(src), str(w2c)


def _slot(tmp_path, name):
    """An existing output folder whose `name` (a file the command writes) is a folder."""
    (tmp_path / "slots" / name).mkdir(parents=True)
    return str(tmp_path / "slots")


# (argv with {S} = source map, {W} = w2c, {T} = tmp folder; words in the error)
OUTPUT_CASES = [
    ("rotate {S} {T}/adir --w2c {W}", "`dst`"),
    ("rotate {S} {T}/afile --w2c {W}", "`dst`"),
    ("rotate {S} {T}/afile/o.exr --w2c {W}", "`dst`"),
    ("rotate {S} {T}/o.png --w2c {W}", "`dst`"),
    ("rotate {S} {T}/o.txt --w2c {W}", "`dst`"),
    ("rotate {S} {S} --w2c {W}", "is the input `src`"),  # would replace the source map
    ("rotate {S} {T}/fifo.exr --w2c {W}", "not a regular file"),  # renaming over it replaces it
    ("rotate {S} {T}/" + "x" * 300 + ".exr --w2c {W}", "`dst`"),  # a name too long to write
    ("rotate {S} {T}/new/" + "x" * 250 + ".exr --w2c {W}", "pass a shorter name"),
    ("encode {T}/in/ldr.png --w2c {W} --out-dir {T}/in", "is the input `src`"),
    ("encode {S} --w2c {W} --out-dir {T}/afile", "`--out-dir`"),
    ("encode {S} --w2c {W} --out-dir {T}/afile/enc", "`--out-dir`"),
    ("encode {S} --w2c {W} --out-dir {T}/slots", "ldr.png is a folder"),
    ("augment {S} --out-dir {T}/afile", "`--out-dir`"),
    ("augment {S} --out-dir {T}/slots --yaw-steps 1", "sky_"),
    ("procedural --out-dir {T}/afile --count 1 --height 8", "`--out-dir`"),
    ("procedural --out-dir {T}/slots --count 1 --height 8", "proc_0000.exr is a folder"),
    ("demo --out {T}/afile --size 16", "`--out`"),
    ("demo --out {T}/slots --size 16", "a file where this command writes a folder"),
]


@pytest.mark.parametrize(("argv", "words"), OUTPUT_CASES)
def test_bad_output_paths_are_refused_before_any_work(tmp_path, capsys, argv, words) -> None:
    src, w2c = _inputs(tmp_path)
    write_png(tmp_path / "in" / "ldr.png", np.full((8, 16, 3), 128, np.uint8))  # an LDR map
    os.mkfifo(tmp_path / "fifo.exr")
    cmd = argv.split()[0]
    if "{T}/slots" in argv:
        slot = {
            "encode": "ldr.png",
            "augment": "sky_f0_y0of1.exr",
            "procedural": "proc_0000.exr",
        }.get(cmd)
        if slot is None:  # demo: a file where its view_0/ folder goes
            (tmp_path / "slots").mkdir()
            (tmp_path / "slots" / "view_0").write_text("x")
        else:
            _slot(tmp_path, slot)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    args = [a.format(S=src, W=w2c, T=tmp_path) for a in argv.split()]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_rotate_to_hdr_without_openimageio_is_refused_before_the_rotation(
    tmp_path, capsys, monkeypatch
) -> None:
    import sys

    import gaffer_envmap.rotate as rotate

    src, w2c = _inputs(tmp_path)
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)  # import OpenImageIO -> ImportError

    def no_work(*_a, **_k):
        raise AssertionError("rotated before the output was checked")

    monkeypatch.setattr(rotate, "rotate_to_camera", no_work)
    assert main(["rotate", src, str(tmp_path / "o.hdr"), "--w2c", w2c]) == 2
    err = capsys.readouterr().err
    assert "`dst`" in err and "gaffer-envmap[hdr]" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o.hdr").exists()


def test_atomic_files_refuses_a_folder_in_a_files_place_before_moving_any(tmp_path) -> None:
    from gaffer_envmap.atomic import atomic_files
    from gaffer_envmap.errors import EnvmapWriteError

    (tmp_path / "b.txt").mkdir()
    with pytest.raises(EnvmapWriteError, match="is a folder"):
        with atomic_files(tmp_path) as stage:
            (stage / "a.txt").write_text("a")
            (stage / "b.txt").write_text("b")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.txt"]  # no a.txt: all or none
