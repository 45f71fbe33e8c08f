"""The command lines' error boundary (issue 17), shared by all four gaffer CLIs: `--debug`, the one-line
report of an expected failure, and the exit-code epilog of `--help`.

A CLI-side module: it writes to stderr, which library modules never do (they raise `GafferError`s).
"""

import argparse
import sys
import traceback

DEBUG_HELP = (
    "on an error, also print the Python traceback to stderr (before the usual one-line message "
    "and exit code)"
)
"""Help text of every gaffer CLI's `--debug` flag."""


def add_debug_argument(parser: argparse.ArgumentParser) -> None:
    """Add `--debug` to `parser` and to each of its subcommands' parsers.

    On the top-level parser it defaults to False; on the subcommands it is `argparse.SUPPRESS`, so
    `gaffer-x --debug cmd ...` and `gaffer-x cmd ... --debug` both work and neither resets the other.
    """
    parser.add_argument("--debug", action="store_true", default=False, help=DEBUG_HELP)
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                sub.add_argument(
                    "--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP
                )


def cli_failure(line: str, code: int, args: object = None) -> int:
    """Report the exception being handled as one stderr line and return the exit `code`.

    Call it inside an `except` block. With `--debug` (`args.debug`), the traceback is printed to
    stderr first; the line and the code are the same either way.
    """
    if getattr(args, "debug", False):
        traceback.print_exc(file=sys.stderr)
    print(line, file=sys.stderr)
    return code


def exit_codes_epilog(codes: "dict[int, str]") -> str:
    """The `--help` epilog listing a CLI's exit codes, e.g. "Exit codes: 0 done; 2 refused; ..."."""
    return "Exit codes: " + "; ".join(f"{code} {meaning}" for code, meaning in codes.items()) + "."
