"""`--debug`, documented exit codes and one `--sanitize` on every gaffer CLI."""

import argparse
import importlib
import re
from pathlib import Path

import pytest

from gaffer_envmap.sanitize import SANITIZE_POLICIES

ROOT = Path(__file__).resolve().parents[2]

# (CLI module, parser factory, the subcommand handler to make fail, argv that reaches it)
CLIS = {
    "gaffer-envmap": ("gaffer_envmap.cli", "build_parser", "_cmd_info", "info x.exr"),
    "gaffer-data": ("gaffer_data.cli", "build_parser", "_info", "info somewhere"),
    "gaffer-diffusion": ("gaffer_diffusion.cli", "_parser", "_demo", "demo --out o"),
    "gaffer-nerf": ("gaffer_nerf.cli", "_parser", "_fit", "fit data --out o"),
}
PARAMS = [pytest.param(*v, id=k) for k, v in CLIS.items()]
FAILURES = [
    (KeyboardInterrupt(), 130, "interrupted (Ctrl-C)"),
    (PermissionError(13, "Permission denied", "out/x.png"), 2, "Permission denied"),
]


@pytest.mark.parametrize(("module", "factory", "handler", "argv"), PARAMS)
@pytest.mark.parametrize(("exc", "code", "words"), FAILURES)
@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_prints_the_traceback_then_the_same_line(
    monkeypatch, capsys, module, factory, handler, argv, exc, code, words, where
):
    cli = pytest.importorskip(module)

    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(cli, handler, fail)
    plain = importlib.import_module(module).main(argv.split())
    line = capsys.readouterr().err.strip()
    debug_argv = ["--debug", *argv.split()] if where == "before" else [*argv.split(), "--debug"]
    assert cli.main(debug_argv) == plain == code
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == "Traceback (most recent call last):" and type(exc).__name__ in "\n".join(err)
    assert err[-1] == line and words in line  # the same one line, last


@pytest.mark.parametrize(("module", "factory", "handler", "argv"), PARAMS)
def test_exit_codes_in_help_and_in_the_docs_table(module, factory, handler, argv):
    cli = pytest.importorskip(module)
    parser = getattr(cli, factory)()
    codes = (
        getattr(cli, "EXIT_CODES", None)
        or importlib.import_module("gaffer_diffusion.cli.parser").EXIT_CODES
    )
    help_text = " ".join(parser.format_help().split())
    assert "Exit codes:" in help_text
    for code in (0, 2, 130):
        assert code in codes and f" {code} " in help_text
    # the documented table has one row per code this CLI returns, and a column for this CLI
    table = (ROOT / "docs" / "cli.md").read_text()
    header = next(row for row in table.splitlines() if row.startswith("| code |"))
    assert f"`{parser.prog}`" in header
    rows = {int(m.group(1)) for m in re.finditer(r"^\| (\d+) \|", table, re.M)}
    assert set(codes) - {1} <= rows and 1 in rows  # 1: partial results (data, diffusion) or a bug


def _sanitize_flags(parser: argparse.ArgumentParser, prefix: str) -> dict[str, argparse.Action]:
    found: dict[str, argparse.Action] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found.update(_sanitize_flags(sub, f"{prefix} {name}"))
        elif "--sanitize" in action.option_strings:
            found[prefix] = action
    return found


def test_every_command_that_reads_env_maps_takes_the_shared_sanitize():
    flags: dict[str, argparse.Action] = {}
    for module, factory, _, _ in CLIS.values():
        parser = getattr(pytest.importorskip(module), factory)()
        flags.update(_sanitize_flags(parser, parser.prog))
    expected = {
        "gaffer-envmap info",
        "gaffer-envmap rotate",
        "gaffer-envmap encode",
        "gaffer-envmap augment",
        "gaffer-data render",
        "gaffer-data render-multiview",
        "gaffer-diffusion relight",
        "gaffer-diffusion evaluate",
        "gaffer-diffusion demo",
        "gaffer-nerf relight",
    }
    assert expected <= set(flags), sorted(expected - set(flags))
    for where, action in flags.items():
        assert tuple(action.choices or ()) == SANITIZE_POLICIES, where
        assert "'strict' refuses any" in (action.help or ""), where  # one help text
        assert f"'{action.default}' (default)" in (action.help or ""), where
        assert action.default == "raise", where  # the library's default everywhere
