"""Atomic file writes: a reader never sees a half-written file, a failed write never clobbers.

Every gaffer-envmap writer goes through `atomic_write`: the payload is written to a temporary file in
the destination's directory (same file system, so the final `os.replace` is atomic), flushed to disk
with `fsync`, then renamed over the destination. On any failure the temporary file is removed and an
existing destination is left byte-for-byte untouched.
"""

import contextlib
import logging
import os
import shutil
import tempfile
from collections.abc import Callable, Collection, Iterator
from pathlib import Path
from typing import TypeVar

from gaffer_envmap.errors import EnvmapWriteError, OutputPathError

__all__ = ["atomic_dir", "atomic_files", "atomic_path", "atomic_write"]

logger = logging.getLogger(__name__)

T = TypeVar("T")

_NEW_FILE_MODE = 0o644


def _fsync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(directory: Path) -> None:
    # Makes the rename itself durable on POSIX; directories cannot be opened on Windows.
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _target_mode(path: Path) -> int:
    try:
        return path.stat().st_mode & 0o777
    except OSError:
        return _NEW_FILE_MODE


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces `path` atomically.

    The temporary file sits beside `path` and keeps its suffix (writers such as OpenImageIO and
    Pillow pick the format from it). It exists (empty) when the block starts.

    Args:
        path: the destination file.

    Yields:
        The temporary path the block must write to.

    Raises:
        EnvmapWriteError: when the parent directory is missing or the block (or the final rename)
            fails. The destination is untouched and the temporary file removed.

    Example:
        >>> import tempfile
        >>> d = Path(tempfile.mkdtemp())
        >>> with atomic_path(d / "out.txt") as tmp:
        ...     _ = tmp.write_text("hello")
        >>> (d / "out.txt").read_text()
        'hello'
    """
    dest = Path(path)
    if not dest.parent.is_dir():
        raise EnvmapWriteError(
            f"Cannot write `path` {str(dest)!r}: its directory {str(dest.parent)!r} does not exist. "
            "Create it first (e.g. `Path(path).parent.mkdir(parents=True)`)."
        )
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{dest.stem}.", suffix=f".tmp{dest.suffix}", dir=dest.parent
        )
    except OSError as exc:
        raise EnvmapWriteError(
            f"Cannot write `path` {str(dest)!r}: creating a temporary file failed ({exc})."
        ) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        _fsync_file(tmp)
        os.chmod(tmp, _target_mode(dest))
        os.replace(tmp, dest)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if not isinstance(exc, Exception):
            raise
        if isinstance(exc, EnvmapWriteError):
            raise
        raise EnvmapWriteError(
            f"Writing `path` {str(dest)!r} failed ({type(exc).__name__}: {exc}); "
            "the destination was left untouched."
        ) from exc
    _fsync_dir(dest.parent)
    logger.debug("wrote %s", dest)


def atomic_write(path: str | os.PathLike[str], write_fn: Callable[[Path], T]) -> T:
    """Call `write_fn(tmp_path)` and atomically move the result to `path`.

    Args:
        path: the destination file.
        write_fn: writes the complete file to the path it is given (a temporary file beside
            `path`, with the same suffix). Its return value is passed through.

    Returns:
        What `write_fn` returned.

    Raises:
        EnvmapWriteError: when `write_fn` raises, or the directory is missing, or the rename
            fails; chained to the original exception. An existing file at `path` is left
            untouched and no temporary file remains.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> d = tempfile.mkdtemp()
        >>> atomic_write(f"{d}/a.bin", lambda tmp: tmp.write_bytes(b"abc"))
        3
        >>> Path(f"{d}/a.bin").read_bytes()
        b'abc'
    """
    with atomic_path(path) as tmp:
        return write_fn(tmp)


@contextlib.contextmanager
def atomic_files(directory: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a staging folder; on success its files move into `directory` together, else none do.

    For commands that write many files (augmentation pools, procedural sets): the files are written
    into a hidden staging folder inside `directory` (same file system), and only when the block ends
    without an error are they renamed into place, one `os.replace` each, a few microseconds apart.
    On an error or Ctrl-C the staging folder is removed, `directory` keeps exactly what it held before,
    and a `directory` this call created is removed again when empty (no partial outputs).
    A kill -9 can leave only the hidden `.partial-*` folder, never a partial set under final names.

    Args:
        directory: the destination folder (created when missing). The staging folder is flat:
            files written into sub-folders of it are not moved.

    Example:
        >>> import tempfile
        >>> from pathlib import Path
        >>> d = Path(tempfile.mkdtemp()) / "maps"
        >>> with atomic_files(d) as stage:
        ...     _ = (stage / "a.txt").write_text("a")
        ...     _ = (stage / "b.txt").write_text("b")
        >>> sorted(p.name for p in d.iterdir())
        ['a.txt', 'b.txt']
    """
    dest = Path(directory)
    created = not dest.exists()
    try:
        dest.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=dest))
    except OSError as exc:
        raise EnvmapWriteError(
            f"Cannot write into `{dest}` ({type(exc).__name__}: {exc}); pick a writable folder."
        ) from exc
    try:
        yield stage
        staged = [f for f in sorted(stage.iterdir()) if f.is_file()]
        # a folder in a file's place would stop the moves half-way: refuse before the first one
        clash = next((dest / f.name for f in staged if (dest / f.name).is_dir()), None)
        if clash is not None:
            raise EnvmapWriteError(
                f"Cannot write `{clash}`: it is a folder; move it away (nothing was written)."
            )
        for f in staged:
            _fsync_file(f)
            os.replace(f, dest / f.name)
        _fsync_dir(dest)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
        if created:
            with contextlib.suppress(OSError):
                dest.rmdir()  # only succeeds when the folder is still empty (a failed run)


@contextlib.contextmanager
def atomic_dir(
    dest: str | os.PathLike[str], *, owned: Collection[str] | None = None
) -> Iterator[Path]:
    """Yield a staging folder; on success it replaces `dest` in one rename, else `dest` is untouched.

    For an output that is a whole folder, sub-folders included (a relit field with its views, the
    demo's pages), which `atomic_files` (flat, one rename per file) cannot publish together: the folder
    is built in a hidden sibling (same file system) and renamed in by one `os.replace`; an earlier
    run's folder is swapped out only then. On an error or Ctrl-C the staging folder is removed and
    `dest` is as it was; a kill -9 can leave only a hidden `.NAME.partial-*` folder beside it.

    Args:
        dest: the output folder (its parent is created when missing).
        owned: the top-level names this output writes. Entries of an earlier `dest` not in it (files
            another tool put there) are moved into the new folder rather than deleted; None: the whole
            folder is this output's.

    Raises:
        OutputPathError: `dest` exists and is not a folder.

    Example:
        >>> d = Path(tempfile.mkdtemp()) / "out"
        >>> with atomic_dir(d, owned=("a.txt", "views")) as stage:
        ...     _ = (stage / "a.txt").write_text("a")
        ...     (stage / "views").mkdir()
        >>> sorted(p.name for p in d.iterdir())
        ['a.txt', 'views']
    """
    dest = Path(dest)
    if dest.exists() and not dest.is_dir():
        raise OutputPathError(f"`--out` {dest} is a file, not a folder; pass a folder.")
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
