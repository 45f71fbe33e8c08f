"""Ctrl-C and unwritable outputs end `gaffer-envmap` with one line on stderr, never a traceback (issue 17)."""

import pytest

from gaffer_envmap.cli import main


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
    monkeypatch.setattr("gaffer_envmap.cli._cmd_info", _raises(exc))
    assert main("info x.exr".split()) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


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
