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
