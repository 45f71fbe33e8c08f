"""Where the gaffer libraries' expected failures become one-line node errors, and the few lookups that
use ComfyUI when it is there (imported inside the functions, never at module level)."""

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from .errors import NodeInputError


@contextlib.contextmanager
def library_errors(node: str, what: str) -> Iterator[None]:
    """Re-raise a gaffer library error (a bad file, an empty mask, a refused value) as a
    `NodeInputError` naming the node and the input (`what`), chained to the original."""
    from gaffer_envmap.errors import GafferError

    try:
        yield
    except NodeInputError:
        raise
    except (GafferError, ValueError, OSError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise NodeInputError(f"{node}: {what}: {first}") from exc


def comfy_input_dir() -> Path | None:
    """ComfyUI's input folder when running inside ComfyUI, else None."""
    try:
        import folder_paths  # type: ignore[import-not-found]  # ComfyUI's own module
    except ImportError:
        return None
    return Path(folder_paths.get_input_directory())


def comfy_models_dir() -> Path | None:
    """ComfyUI's models folder when running inside ComfyUI, else None."""
    try:
        import folder_paths  # type: ignore[import-not-found]
    except ImportError:
        return None
    return Path(folder_paths.models_dir)


def comfy_device() -> str:
    """ComfyUI's torch device inside ComfyUI; elsewhere cuda when available, else cpu."""
    try:
        import comfy.model_management  # type: ignore[import-not-found]

        return str(comfy.model_management.get_torch_device())
    except ImportError:
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"


class Progress:
    """ComfyUI's progress bar on the node when running inside ComfyUI; a no-op elsewhere."""

    def __init__(self, total: int) -> None:
        self._bar: Any = None
        try:
            import comfy.utils  # type: ignore[import-not-found]

            self._bar = comfy.utils.ProgressBar(total)
        except ImportError:
            pass

    def update(self, n: int) -> None:
        if self._bar is not None:
            self._bar.update(n)
