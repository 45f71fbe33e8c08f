"""An output folder that is complete or absent: built in a hidden sibling, renamed into place once.

`relight` writes a field (weights, config, report) and its relit views (a sub-folder), so the
per-file staging of `gaffer_envmap.atomic.atomic_files` (flat, one rename per file) cannot publish
the set together. `atomic_output_dir` builds the whole folder beside its destination (same file
system) and renames it in one `os.replace`; an earlier run's folder is swapped out only then, and
entries of it that this output does not write (another tool's files) move into the new folder.

On an error or Ctrl-C the staging folder is removed and the destination is as it was; a kill -9 can
leave only a hidden `.NAME.partial-*` folder beside it, never part of a set under the final name.
"""

import contextlib
import os
import shutil
import tempfile
from collections.abc import Collection, Iterator
from pathlib import Path

from gaffer_nerf.errors import ConfigError


@contextlib.contextmanager
def atomic_output_dir(dest: Path, *, owned: Collection[str]) -> Iterator[Path]:
    """Yield a staging folder; when the block ends without an error it becomes `dest` in one rename.

    Args:
        dest: the output folder (its parent is created when missing).
        owned: the top-level names this output writes; an earlier `dest`'s other entries are kept
            (moved into the new folder), its entries of these names are replaced as a whole.

    Raises:
        ConfigError: `dest` exists and is not a folder.

    Example:
        >>> import tempfile
        >>> d = Path(tempfile.mkdtemp()) / "out"
        >>> with atomic_output_dir(d, owned=("a.txt", "views")) as stage:
        ...     _ = (stage / "a.txt").write_text("a")
        ...     (stage / "views").mkdir()
        >>> sorted(p.name for p in d.iterdir())
        ['a.txt', 'views']
    """
    dest = Path(dest)
    if dest.exists() and not dest.is_dir():
        raise ConfigError(f"`--out` {dest} is a file, not a folder; pass a folder.")
    parent = dest.absolute().parent
    parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{dest.name}.partial-", dir=parent))
    try:
        yield stage
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    old: Path | None = None
    kept: list[str] = []  # the earlier folder's foreign entries, moved into the new one
    try:
        if dest.exists():
            for entry in sorted(dest.iterdir()):
                if entry.name not in owned and not (stage / entry.name).exists():
                    os.replace(entry, stage / entry.name)
                    kept.append(entry.name)
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old-", dir=parent))
            os.replace(dest, old / dest.name)
        os.replace(stage, dest)
    except BaseException:
        if old is not None and not dest.exists() and (old / dest.name).exists():
            os.replace(old / dest.name, dest)  # the earlier run back
        if dest.is_dir() and stage.exists():
            for name in kept:  # with the entries that were not ours
                with contextlib.suppress(OSError):
                    os.replace(stage / name, dest / name)
        shutil.rmtree(stage, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
