"""Multi-file outputs that are complete or absent (an interrupted run leaves no half-written set):
built in a hidden sibling, then moved.

`atomic_dir` builds a whole output folder (the demo's) in a temporary sibling and renames it into
place only when the block ends without an error; an earlier run's folder stays as it was until then.
`staged_files` does the same for a set of files that share a prefix in a folder the user owns (the
`relight --turntable` frames and animation): the new set is written to a hidden staging folder, and
only when it is complete are the earlier run's files of that prefix removed and the new ones moved in.

On an error or Ctrl-C the staging folder is removed; a kill -9 can leave only a hidden
`.NAME.partial-*` folder beside the output, never a mix of old and new files under the final names.
"""

import contextlib
import os
import shutil
import tempfile
from collections.abc import Collection, Iterator
from pathlib import Path

from gaffer_diffusion.errors import ConfigError


@contextlib.contextmanager
def atomic_dir(dest: Path, *, owned: Collection[str] | None = None) -> Iterator[Path]:
    """Yield a staging folder; on success it replaces `dest` in one rename, else `dest` is untouched.

    Args:
        dest: the output folder (its parent is created when missing).
        owned: the top-level names this output writes. Entries of an existing `dest` not in it (files
            another tool put there, e.g. the demo's `envmap/`) are moved into the new folder rather
            than deleted; None: the whole folder is this output's.

    Raises:
        ConfigError: `dest` exists and is not a folder.
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
    kept: list[str] = []  # foreign entries moved from the earlier folder into the new one
    try:
        if dest.exists():
            if owned is not None:
                for entry in sorted(dest.iterdir()):
                    if entry.name not in owned and not (stage / entry.name).exists():
                        os.replace(entry, stage / entry.name)
                        kept.append(entry.name)
            old = Path(tempfile.mkdtemp(prefix=f".{dest.name}.old-", dir=parent))
            os.replace(dest, old / dest.name)
        os.replace(stage, dest)
    except BaseException:
        if old is not None and not dest.exists() and (old / dest.name).exists():
            os.replace(old / dest.name, dest)  # put the earlier run back
        if dest.is_dir() and stage.exists():
            for name in kept:  # and the entries that were not ours
                with contextlib.suppress(OSError):
                    os.replace(stage / name, dest / name)
        shutil.rmtree(stage, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def staged_files(folder: Path, stale: Collection[str]) -> Iterator[Path]:
    """Yield a staging folder; on success its files move into `folder` and the earlier run's files
    matching the glob patterns `stale` (not written again) are removed; on an error nothing changes.

    Args:
        folder: where the files go (created when missing).
        stale: glob patterns, relative to `folder`, of an earlier run's files of this output.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=folder))
    try:
        yield stage
        new = sorted(p for p in stage.iterdir() if p.is_file())
        names = {p.name for p in new}
        for pattern in stale:
            for old in folder.glob(pattern):
                if old.is_file() and old.name not in names:
                    old.unlink()
        for p in new:
            os.replace(p, folder / p.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
