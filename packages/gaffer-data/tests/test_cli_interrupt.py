"""Ctrl-C and unwritable outputs end `gaffer-data` with one line on stderr, never a traceback (issue 17)."""

import pytest

from gaffer_data.cli import main


def _raises(exc: BaseException):
    def handler(*args, **kwargs):
        raise exc

    return handler


@pytest.mark.parametrize(
    ("exc", "code", "words"),
    [
        (KeyboardInterrupt(), 130, "interrupted (Ctrl-C)"),
        (PermissionError(13, "Permission denied", "out/x.png"), 2, "Permission denied"),
        (NotADirectoryError(20, "Not a directory", "out"), 2, "Not a directory"),
    ],
)
def test_one_line_and_an_exit_code(monkeypatch, capsys, exc, code, words) -> None:
    monkeypatch.setattr("gaffer_data.cli._info", _raises(exc))
    assert main("info somewhere".split()) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("argv", "words"),
    [(["recipe", "r", "--procedural", "-1"], "--procedural"), (["recipe", ""], "`out` is empty")],
)
def test_recipe_refuses_nonsense_and_writes_nothing(tmp_path, monkeypatch, capsys, argv, words):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
