"""Ctrl-C and unwritable outputs end `gaffer-diffusion` with one line on stderr, never a traceback (issue 17)."""

import pytest

from gaffer_diffusion.cli import main


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
    monkeypatch.setattr("gaffer_diffusion.cli._demo", _raises(exc))
    assert main("demo --out o".split()) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
