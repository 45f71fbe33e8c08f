"""Check every gaffer command shown in the docs against the real command-line parsers.

Called by `make_figures.main` at every docs build (so a renamed or removed flag fails the build) and
runnable alone: `python docs/_scripts/check_commands.py`. It reads the ```bash blocks of every page,
joins `\\`-continued lines, drops comments, and hands the arguments of each `gaffer-envmap`,
`gaffer-data`, `gaffer-diffusion` and `gaffer-nerf` command (also as `python -m <pkg>.cli` or after
`accelerate launch ... -m <pkg>.cli`) to that package's argparse parser. Nothing is executed: a command
passes when the parser accepts it (placeholders such as `model/` are fine).
"""

import argparse
import contextlib
import importlib
import io
import re
import shlex
from collections.abc import Callable
from pathlib import Path

DOCS = Path(__file__).resolve().parent.parent

# command -> (module, name of the function that builds its parser)
PARSERS = {
    "gaffer-envmap": ("gaffer_envmap.cli", "build_parser"),
    "gaffer-data": ("gaffer_data.cli", "build_parser"),
    "gaffer-diffusion": ("gaffer_diffusion.cli", "_parser"),
    "gaffer-nerf": ("gaffer_nerf.cli", "_parser"),
}
MODULES = {module: command for command, (module, _) in PARSERS.items()}
_BLOCK = re.compile(r"^```(?:bash|console|shell|sh)\s*$(.*?)^```\s*$", re.M | re.S)


def _parser(command: str) -> argparse.ArgumentParser:
    module, name = PARSERS[command]
    build: Callable[[], argparse.ArgumentParser] = getattr(importlib.import_module(module), name)
    return build()


def commands(text: str) -> list[list[str]]:
    """The argument lists of the gaffer commands in the shell blocks of one page."""
    found = []
    for block in _BLOCK.findall(text):
        for line in block.replace("\\\n", " ").splitlines():
            try:
                argv = shlex.split(line, comments=True)
            except ValueError:
                continue
            if not argv:
                continue
            if argv[0] in PARSERS:
                found.append(argv)
            elif "-m" in argv:
                k = argv.index("-m")
                module = argv[k + 1] if k + 1 < len(argv) else ""
                if module in MODULES:
                    found.append([MODULES[module], *argv[k + 2 :]])
    return found


def check(docs: Path = DOCS) -> int:
    """Parse every command; raise `ValueError` listing the ones a parser rejects. Returns the count."""
    errors, count = [], 0
    for page in sorted(docs.rglob("*.md")):
        if "_build" in page.parts or "_generated" in page.parts:
            continue
        for argv in commands(page.read_text()):
            count += 1
            err = io.StringIO()
            try:
                with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                    _parser(argv[0]).parse_args(argv[1:])
            except SystemExit as exc:
                if exc.code not in (0, None):
                    msg = err.getvalue().strip().splitlines()[-1:] or ["rejected"]
                    errors.append(f"{page.relative_to(docs)}: `{shlex.join(argv)}`: {msg[0]}")
    if errors:
        raise ValueError("commands in the docs that the CLI rejects:\n" + "\n".join(errors))
    return count


if __name__ == "__main__":
    print(f"check_commands: {check()} commands accepted")
