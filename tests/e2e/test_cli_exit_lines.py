"""Every gaffer CLI ends Ctrl-C and unwritable outputs with one stderr line, never a traceback."""

import importlib

import pytest

# (CLI module, the subcommand handler to make fail, argv that reaches it)
CLIS = [
    ("gaffer_envmap.cli", "_cmd_info", "info x.exr"),
    ("gaffer_data.cli", "_info", "info somewhere"),
    ("gaffer_diffusion.cli", "_demo", "demo --out o"),
    ("gaffer_nerf.cli", "_fit", "fit data --out o"),
]
FAILURES = [
    (KeyboardInterrupt(), 130, "interrupted (Ctrl-C)"),
    (PermissionError(13, "Permission denied", "out/x.png"), 2, "Permission denied"),
    (NotADirectoryError(20, "Not a directory", "out"), 2, "Not a directory"),
]


@pytest.mark.parametrize(("module", "handler", "argv"), CLIS)
@pytest.mark.parametrize(("exc", "code", "words"), FAILURES)
def test_one_line_and_an_exit_code(monkeypatch, capsys, module, handler, argv, exc, code, words):
    cli = pytest.importorskip(module)

    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(cli, handler, fail)
    assert importlib.import_module(module).main(argv.split()) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
