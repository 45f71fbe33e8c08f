"""What the page's tabs share: error display, per-request output folders, saving PNGs, picking a map.

Import this module only after `server.py` has set Gradio's environment (as `_ui.py`).
"""

import functools
import hashlib
import html
import itertools
import logging
import re
import shutil
import threading
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import gradio as gr
import numpy as np

from gaffer_diffusion.errors import GafferDiffusionError
from gaffer_envmap.writers import write_png

logger = logging.getLogger(__name__)

ENVMAP_SUFFIXES = (".exr", ".hdr")
"""Uploads the environment-map field accepts (gaffer-envmap reads both)."""

OUTPUT_BUTTONS: list[Any] = ["download", "fullscreen"]
"""Buttons on result images (no "share": that uploads to Hugging Face Spaces)."""

KEEP_JOBS = 8
"""Output folders kept on disk; older ones are deleted (Gradio has copied what the page shows)."""

F = TypeVar("F", bound=Callable[..., Any])

_CACHE_DIRS = re.compile(r"[^\s'\"`]*/[0-9a-f]{64}/")
"""Gradio's upload cache folders (`.../<sha256>/`), cut from messages: the file name is what a user knows."""


def _page_message(exc: BaseException) -> str:
    """`exc`'s message for the page: no server paths, HTML special characters escaped."""
    return html.escape(_CACHE_DIRS.sub("", str(exc)), quote=False)


def shown_in_page(title: str) -> Callable[[F], F]:
    """A decorator turning the library's expected errors into a `gr.Error` the page shows as one
    readable message under `title` ("Cannot relight", "Cannot insert")."""
    return functools.partial(_shown_in_page, title=title)  # type: ignore[return-value]


def _shown_in_page(fn: F, *, title: str) -> F:
    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except gr.Error:
            raise
        except Exception as exc:
            # gaffer-envmap's errors (unreadable EXR, not 2:1) carry their own fix, like ours
            ours = isinstance(exc, GafferDiffusionError) or type(exc).__module__.startswith(
                "gaffer_envmap"
            )
            if not ours and not isinstance(exc, OSError | ValueError):
                logger.exception("unexpected error in %s", fn.__name__)
                raise gr.Error(
                    f"Internal error ({type(exc).__name__}); the server log has the details."
                ) from exc
            logger.info("%s refused: %s", fn.__name__, exc)
            raise gr.Error(_page_message(exc), title=title, print_exception=False) from exc

    return wrapper  # type: ignore[return-value]


class Jobs:
    """Per-request output folders under the app's temporary root, only the newest `KEEP_JOBS` kept."""

    def __init__(self, root: Path) -> None:
        self._root = root
        self._dirs: deque[Path] = deque()
        self._count = itertools.count()
        self._lock = threading.Lock()

    def new(self) -> Path:
        with self._lock:
            path = self._root / f"job-{next(self._count):06d}"
            path.mkdir(parents=True)
            self._dirs.append(path)
            while len(self._dirs) > KEEP_JOBS:
                shutil.rmtree(self._dirs.popleft(), ignore_errors=True)
        return path


def digest(path: str | Path) -> str:
    """SHA-256 of a file (Gradio keeps an upload's bytes, so the automatic mask is recognised)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def save_png(path: Path, arr: np.ndarray) -> str:
    """A uint8 image as a PNG for the page, written atomically (`gaffer_envmap.writers`)."""
    return str(write_png(path, arr))


def envmap_path(bundled: str | None, upload: str | None) -> str:
    """The uploaded map if there is one, else the chosen bundled HDRI."""
    from gaffer_envmap.bundled import bundled_hdri

    if upload:
        if Path(upload).suffix.lower() not in ENVMAP_SUFFIXES:
            raise gr.Error(
                f"The environment map must be an .exr or .hdr file, not {html.escape(Path(upload).name, quote=False)}.",
                title="Cannot relight",
                print_exception=False,
            )
        return upload
    if not bundled:
        raise gr.Error("Choose a bundled HDRI or upload an .exr/.hdr map.", print_exception=False)
    return str(bundled_hdri(bundled))
