"""Atomic file writes: write to a temporary sibling, fsync, then `os.replace` onto the final name.

A reader (or a resumed run) therefore sees either no file or a complete one, even after kill -9.
Temporary names start with `.` and contain `.tmp-`, so `remove_stale_temporaries` can clean them.
"""

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

TMP_MARK = ".tmp-"


def temporary_sibling(path: Path) -> Path:
    """A unique hidden temporary path beside `path` that keeps its suffix (Blender picks formats by it)."""
    path = Path(path)
    return path.with_name(f".{path.stem}{TMP_MARK}{os.getpid()}{path.suffix}")


def atomic_write(path: Path, write_fn: Callable[[Path], None]) -> Path:
    """Call `write_fn(tmp)` then move `tmp` onto `path` atomically.

    Args:
        path: the final file path; its folder is created.
        write_fn: writes the complete file to the path it is given.

    Returns:
        `path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_sibling(path)
    try:
        write_fn(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def atomic_write_text(path: Path, text: str) -> Path:
    """Atomically write UTF-8 text."""
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def atomic_write_json(path: Path, data: Any) -> Path:
    """Atomically write indented, key-sorted JSON."""
    return atomic_write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n")


def remove_stale_temporaries(folder: Path) -> int:
    """Delete temporaries left by killed writers under `folder`; returns how many were removed."""
    count = 0
    if not Path(folder).is_dir():
        return 0
    for tmp in Path(folder).rglob(f".*{TMP_MARK}*"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)
            count += 1
    return count
