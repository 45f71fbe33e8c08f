"""Thin helpers on top of `gaffer_envmap.atomic` (the one atomic-write implementation of gaffer).

`gaffer_envmap.atomic.atomic_write(path, write_fn)` writes to a hidden temporary sibling, fsyncs and
`os.replace`s it, so a reader (or a resumed run) sees either no file or a complete one, even after
kill -9. It needs the destination folder to exist; the helpers here create it, add text and JSON
writers, and clean the temporaries that a killed writer leaves behind.

Importing this module pulls in numpy only (no torch), so the Blender worker may use it.
"""

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from gaffer_envmap.atomic import atomic_write as _envmap_atomic_write

T = TypeVar("T")

# gaffer_envmap.atomic names its temporaries `tempfile.mkstemp(prefix=".{stem}.",
# suffix=".tmp{suffix}")`: a dot, the stem, a dot, 8 random characters, ".tmp", then the suffix.
_STALE_TEMPORARY = re.compile(r"^\..*\.[A-Za-z0-9_]{8}\.tmp(\.[^.]+)?$")


def atomic_write(path: Path, write_fn: Callable[[Path], T]) -> T:
    """`gaffer_envmap.atomic.atomic_write` after creating `path`'s folder.

    Args:
        path: the final file path.
        write_fn: writes the complete file to the temporary path it is given (same suffix as `path`).

    Returns:
        What `write_fn` returned.

    Raises:
        gaffer_envmap.errors.EnvmapWriteError: `write_fn` or the rename failed (an `OSError`); an
            existing file at `path` is left untouched.
    """
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return _envmap_atomic_write(path, write_fn)


def atomic_write_text(path: Path, text: str) -> Path:
    """Atomically write UTF-8 text to `path` (its folder is created); returns `path`."""
    atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))
    return Path(path)


def atomic_write_json(path: Path, data: Any) -> Path:
    """Atomically write indented, key-sorted JSON to `path`; returns `path`."""
    return atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def is_stale_temporary(path: Path) -> bool:
    """Whether `path` is named like a temporary of `gaffer_envmap.atomic` (hidden, `.tmp` marked)."""
    return bool(_STALE_TEMPORARY.match(Path(path).name))


def remove_stale_temporaries(folder: Path) -> int:
    """Delete temporaries that killed writers left under `folder` (recursively).

    `gaffer_envmap.atomic` removes its temporary on any exception, but not after kill -9; a resumed
    render calls this on the object's folder before its worker starts (so no writer is running there).

    Args:
        folder: the folder to clean; a missing folder is fine.

    Returns:
        How many files were removed.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    count = 0
    for tmp in folder.rglob(".*"):
        if tmp.is_file() and is_stale_temporary(tmp):
            tmp.unlink(missing_ok=True)
            count += 1
    return count
