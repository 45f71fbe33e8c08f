"""Every argument of every gaffer CLI has help text."""

import argparse

import pytest

# (CLI module, the function that builds its parser)
CLIS = {
    "gaffer-envmap": ("gaffer_envmap.cli", "build_parser"),
    "gaffer-data": ("gaffer_data.cli", "build_parser"),
    "gaffer-diffusion": ("gaffer_diffusion.cli", "_parser"),
    "gaffer-nerf": ("gaffer_nerf.cli", "_parser"),
}
HELP_PARAMS = [pytest.param(*CLIS[name], id=name) for name in CLIS]
RENDER_PARAMS = [pytest.param(*CLIS[name], id=name) for name in CLIS]


def _walk(parser: argparse.ArgumentParser, prefix: str) -> list[tuple[str, argparse.Action]]:
    """(command path, action) of every action of `parser` and of its subcommands' parsers."""
    found: list[tuple[str, argparse.Action]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += _walk(sub, f"{prefix} {name}")
        elif not isinstance(action, argparse._HelpAction):
            found.append((prefix, action))
    return found


def _subcommands_without_help(parser: argparse.ArgumentParser, prefix: str) -> list[str]:
    missing = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helped = {a.dest for a in action._choices_actions if a.help}
            for name, sub in action.choices.items():
                if name not in helped and sub.description is None:
                    missing.append(f"{prefix} {name}")
                missing += _subcommands_without_help(sub, f"{prefix} {name}")
    return missing


@pytest.mark.parametrize(("module", "factory"), HELP_PARAMS)
def test_every_argument_has_help(module: str, factory: str) -> None:
    cli = pytest.importorskip(module)
    parser = getattr(cli, factory)()
    actions = _walk(parser, parser.prog)
    assert actions, "no arguments found: is this the parser?"
    missing = [
        f"{where} {'/'.join(a.option_strings) or a.dest}" for where, a in actions if not a.help
    ]
    missing += _subcommands_without_help(parser, parser.prog)
    assert missing == [], f"{len(missing)} of {len(actions)} arguments have no help text"


@pytest.mark.parametrize(("module", "factory"), RENDER_PARAMS)
def test_every_help_page_renders(module: str, factory: str) -> None:
    """A bad `%` format in a help text fails only when the page is printed."""
    cli = pytest.importorskip(module)
    parser = getattr(cli, factory)()
    pages = [parser]
    while pages:
        page = pages.pop()
        assert page.format_help()
        for action in page._actions:
            if isinstance(action, argparse._SubParsersAction):
                pages += list(action.choices.values())
