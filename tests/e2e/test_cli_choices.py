"""Every `--compat` flag of every CLI offers gaffer-envmap's one list of modes."""

import argparse

import pytest

from gaffer_envmap.compat_mode import COMPAT_MODES

CLIS = {
    "gaffer-envmap": ("gaffer_envmap.cli", "build_parser"),
    "gaffer-diffusion": ("gaffer_diffusion.cli", "_parser"),
    "gaffer-nerf": ("gaffer_nerf.cli", "_parser"),
}


def _compat_flags(
    parser: argparse.ArgumentParser, prefix: str
) -> list[tuple[str, argparse.Action]]:
    found: list[tuple[str, argparse.Action]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += _compat_flags(sub, f"{prefix} {name}")
        elif "--compat" in action.option_strings:
            found.append((prefix, action))
    return found


@pytest.mark.parametrize(("module", "factory"), [pytest.param(*v, id=k) for k, v in CLIS.items()])
def test_every_compat_flag_offers_the_shared_modes(module: str, factory: str) -> None:
    cli = pytest.importorskip(module)
    parser = getattr(cli, factory)()
    flags = _compat_flags(parser, parser.prog)
    assert flags, "no --compat flag found: is this the parser?"
    wrong = [
        f"{where}: {a.choices}" for where, a in flags if tuple(a.choices or ()) != COMPAT_MODES
    ]
    assert wrong == []
