"""The command lines' error boundary, shared by all four gaffer CLIs: `--debug`, the one-line
report of an expected failure, the exit-code epilog of `--help`, and the output-path checks every
command runs before any work (`check_output_file`, `check_output_dir`).

A CLI-side module: it writes to stderr, which library modules never do (they raise `GafferError`s).
"""

import argparse
import glob
import os
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterable
from pathlib import Path

from gaffer_envmap.errors import OutputPathError

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


def _nearest_existing(path: Path) -> Path:
    probe = path.absolute()
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    return probe


def _can_create_in(folder: Path) -> bool:
    """A file can be made in `folder` (a probe, removed at once: permission bits alone do not tell
    for root, read-only mounts or /proc)."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


_TEMP_NAME_EXTRA = 16
"""Bytes the atomic writers add to a name for their temporary file (`.NAME.XXXXXXXX.tmp.SUFFIX`)."""


def _check_creatable(flag: str, path: Path, shown: Path) -> None:
    """`path` (absent) can be created: its nearest existing ancestor is a writable folder, and no
    name to be made below it is longer than the file system allows."""
    anc = _nearest_existing(path)
    if not anc.is_dir():
        raise OutputPathError(
            f"`{flag}` {shown} cannot be created: {anc} is a file, not a folder; pass another path."
        )
    if not os.access(anc, os.W_OK | os.X_OK) or not _can_create_in(anc):
        raise OutputPathError(
            f"`{flag}` {shown} cannot be created: {anc} is not writable; pass a path in a writable "
            "folder."
        )
    try:
        name_max = os.pathconf(anc, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):  # not POSIX, or the file system does not say
        return
    limit = name_max - _TEMP_NAME_EXTRA
    for part in path.absolute().relative_to(anc).parts:
        if len(os.fsencode(part)) > limit:
            raise OutputPathError(
                f"`{flag}` {shown} cannot be created: the name {part[:40]!r}... is "
                f"{len(os.fsencode(part))} bytes, over the {limit} this file system leaves for it "
                f"(its limit is {name_max}, and the atomic write names a temporary file after it); "
                "pass a shorter name."
            )


def _guarded(flag: str, path: object, check: Callable[[], None]) -> None:
    """Run `check`; an OS error on the way (a name too long to look up, a loop of links) is refused
    as the argument's error rather than surfacing as a bare `OSError`."""
    try:
        check()
    except OutputPathError:
        raise
    except OSError as exc:
        raise OutputPathError(
            f"`{flag}` {path} cannot be used: {exc.strerror or exc}; pass another path."
        ) from exc


def check_output_file(
    flag: str,
    path: str | os.PathLike[str],
    *,
    suffixes: Iterable[str] | None = None,
    siblings: Iterable[str | os.PathLike[str]] = (),
) -> None:
    """Refuse, before any work, an output file that cannot be written as asked.

    Args:
        flag: the argument's name as the user typed it (`--out`, `dst`), named in the message.
        path: the file the command will write.
        suffixes: the suffixes the command can write (lower case, with the dot); None: any.
        siblings: other files the command writes with it (e.g. `OUT.mask.png`): none may be a folder.

    Raises:
        OutputPathError: the path is empty, a folder, has a suffix not in `suffixes`, sits under a
            file, or cannot be created or replaced (permissions); a sibling is a folder. The message
            names `flag` and the fix.
    """
    _guarded(flag, path, lambda: _check_output_file(flag, Path(path), suffixes, siblings))


def _check_output_file(
    flag: str,
    p: Path,
    suffixes: Iterable[str] | None,
    siblings: Iterable[str | os.PathLike[str]],
) -> None:
    allowed = None if suffixes is None else tuple(suffixes)
    if str(p) in ("", "."):
        raise OutputPathError(f"`{flag}` is empty; pass an output file name.")
    if p.is_dir():
        example = p / f"out{allowed[0] if allowed else ''}"
        raise OutputPathError(f"`{flag}` {p} is a folder; pass a file name (e.g. {example}).")
    if allowed is not None:
        if p.suffix.lower() not in allowed:
            raise OutputPathError(
                f"`{flag}` {p} has suffix {p.suffix or '(none)'!r}; pass a {' or '.join(allowed)} file."
            )
    for sib in siblings:
        if Path(sib).is_dir():
            raise OutputPathError(
                f"`{flag}` {p}: {sib} is a folder where this command writes a file beside the "
                "output; move it away or pass another output name."
            )
    if p.exists():
        if not p.is_file():  # a device, FIFO or socket: the atomic rename would replace the node
            raise OutputPathError(
                f"`{flag}` {p} is not a regular file (a device, pipe or socket); pass a file path."
            )
        if not os.access(p, os.W_OK) or not os.access(p.absolute().parent, os.W_OK | os.X_OK):
            raise OutputPathError(f"`{flag}` {p} exists and cannot be replaced (permissions).")
        return
    _check_creatable(flag, p.absolute(), p)


def check_output_dir(
    flag: str,
    path: str | os.PathLike[str],
    *,
    files: Iterable[str] = (),
    folders: Iterable[str] = (),
) -> None:
    """Refuse, before any work, an output folder that cannot be written as asked.

    Args:
        flag: the argument's name as the user typed it (`--out`, `--out-dir`), named in the message.
        path: the folder the command writes into (created when missing).
        files: names (or glob patterns) of the files the command writes directly in it: an existing
            folder by that name would make the last move of a complete set fail half-way.
        folders: names of the sub-folders the command writes in it: none may be a file.

    Raises:
        OutputPathError: the path is empty, a file, under a file, not writable, or one of the
            `files` is a folder or one of the `folders` a file. The message names `flag` and the fix.
    """
    if str(path) == "":
        raise OutputPathError(f"`{flag}` is empty; pass an output folder.")
    _guarded(flag, path, lambda: _check_output_dir(flag, Path(path), files, folders))


def _check_output_dir(flag: str, p: Path, files: Iterable[str], folders: Iterable[str]) -> None:
    if p.exists() and not p.is_dir():
        raise OutputPathError(
            f"`{flag}` {p} is a file, not a folder; pass a folder (it is created when missing)."
        )
    if not p.exists():
        _check_creatable(flag, p, p)
        return
    if not os.access(p, os.W_OK | os.X_OK) or not _can_create_in(p):
        raise OutputPathError(f"`{flag}` {p} is not writable (permissions); pass another folder.")
    for name in files:
        hits = (
            glob.glob(glob.escape(str(p)) + os.sep + name) if glob.has_magic(name) else [p / name]
        )
        for hit in map(Path, hits):
            if hit.is_dir():
                raise OutputPathError(
                    f"`{flag}` {p}: {hit} is a folder where this command writes a file; move it "
                    "away or pass another folder."
                )
    for name in folders:
        sub = p / name
        if sub.exists() and not sub.is_dir():
            raise OutputPathError(
                f"`{flag}` {p}: {sub} is a file where this command writes a folder; move it away "
                "or pass another folder."
            )


def check_not_an_input(
    flag: str,
    path: str | os.PathLike[str],
    inputs: Iterable[tuple[str, str | os.PathLike[str] | None]],
) -> None:
    """Refuse an output that is one of the command's inputs: writing it would replace the input.

    Args:
        flag: the output argument's name, named in the message.
        path: the output file or folder.
        inputs: `(argument name, path)` of the inputs (None entries are skipped).

    Raises:
        OutputPathError: `path` is (or resolves to) one of `inputs`.
    """
    out = Path(path)
    for name, given in inputs:
        if given is None or str(given) == "":
            continue
        src = Path(given)
        try:
            same = out.exists() and src.exists() and os.path.samefile(out, src)
        except OSError:
            same = False
        if same or out.absolute().resolve() == src.absolute().resolve():
            raise OutputPathError(
                f"`{flag}` {out} is the input `{name}`: writing it would replace the input; pass "
                "another output path."
            )


def output_path(text: str) -> Path:
    """argparse type of an output path: a `Path`, refusing an empty string (`--out "$UNSET"`), which
    `Path("")` would silently turn into the current folder."""
    if not text.strip():
        raise argparse.ArgumentTypeError(
            "is empty; pass an output path (use . for the current folder)"
        )
    return Path(text)
