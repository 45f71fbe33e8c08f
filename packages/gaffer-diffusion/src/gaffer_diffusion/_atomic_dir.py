"""Multi-file outputs that are complete or absent (an interrupted run leaves no half-written set):
built in a hidden sibling, then moved.

`atomic_dir` (gaffer-envmap's, re-exported) builds a whole output folder (the demo's) in a temporary
sibling and renames it into place only when the block ends without an error; an earlier run's folder
stays as it was until then.
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

from gaffer_envmap.atomic import atomic_dir as atomic_dir  # the one folder publisher


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
