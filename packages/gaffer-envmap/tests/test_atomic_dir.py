"""`gaffer_envmap.atomic.atomic_dir`: a whole output folder published complete or not at all."""

from pathlib import Path

import pytest

from gaffer_envmap.atomic import atomic_dir
from gaffer_envmap.errors import OutputPathError


def _tree(d: Path) -> dict[str, str]:
    return {p.relative_to(d).as_posix(): p.read_text() for p in sorted(d.rglob("*")) if p.is_file()}


def test_a_failure_midway_leaves_the_earlier_run_and_no_staging(tmp_path: Path) -> None:
    out = tmp_path / "out"
    with atomic_dir(out, owned=("a.txt", "views")) as stage:
        (stage / "a.txt").write_text("run 1")
        (stage / "views").mkdir()
        (stage / "views" / "0.png").write_text("v1")
    (out / "notes.md").write_text("the user's")  # not this output's: kept across runs
    before = _tree(out)
    with (
        pytest.raises(RuntimeError, match="boom"),
        atomic_dir(out, owned=("a.txt", "views")) as stage,
    ):
        (stage / "a.txt").write_text("run 2")
        raise RuntimeError("boom")
    assert _tree(out) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no .out.partial-* left
    with atomic_dir(out, owned=("a.txt", "views")) as stage:
        (stage / "a.txt").write_text("run 3")
    # the owned sub-folder of the earlier run is replaced as a whole; the user's file is kept
    assert _tree(out) == {"a.txt": "run 3", "notes.md": "the user's"}


def test_a_file_in_place_of_the_folder_is_refused_before_work(tmp_path: Path) -> None:
    f = tmp_path / "out"
    f.write_text("x")
    with pytest.raises(OutputPathError, match="is a file, not a folder; pass a folder"):
        with atomic_dir(f):
            pytest.fail("the block must not run")
    assert f.read_text() == "x"
