"""Reading the lighting files of `relight` and `insert`, each once per call (`cli._from_args` calls
these): the camera of `--w2c` and an environment map with `--sanitize`, each refused in one line
naming the flag; and the early check of an `--envmap` value (a file, or a bundled HDRI's name)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.errors import InputValueError

if TYPE_CHECKING:
    import numpy as np


def _read_w2c(path: Path) -> np.ndarray:
    """`--w2c`: a 3x4 or 4x4 float .npy (no pickles), refused with one line otherwise."""
    import numpy as np

    checks.need_file("--w2c", path, "a 3x4 or 4x4 world-to-camera .npy (numpy.save)")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputValueError(
            f"`--w2c` {path} is not a plain numeric .npy ({exc}); save the 3x4 or 4x4 matrix with "
            "numpy.save (no pickled objects)."
        ) from exc
    if (
        not isinstance(arr, np.ndarray)
        or arr.dtype.kind not in "fiu"
        or arr.shape not in ((3, 4), (4, 4))
    ):
        shape = getattr(arr, "shape", None)
        raise InputValueError(
            f"`--w2c` {path} holds {getattr(arr, 'dtype', type(arr).__name__)} of shape {shape}; "
            "pass a 3x4 or 4x4 float world-to-camera matrix."
        )
    if not np.isfinite(arr).all():
        raise InputValueError(f"`--w2c` {path} holds NaN or Inf; pass a finite matrix.")
    return arr.astype(np.float64)


def _read_envmap(envmap: Path, policy: str) -> Any:
    """`envmap` read with `--sanitize` `policy` (numpy only); a refused map is one line naming the
    flag."""
    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.sanitize import sanitize_flag_refusal

    try:
        return read_envmap(envmap, sanitize=policy)  # type: ignore[arg-type]
    except NonFiniteError as exc:
        raise InputValueError(sanitize_flag_refusal(exc, policy)) from exc


def _check_envmap_arg(path: Path) -> None:
    if not path.exists() and not path.suffix:
        from gaffer_envmap.bundled import bundled_hdris

        names = ", ".join(sorted(bundled_hdris()))
        raise InputValueError(
            f"`--envmap` {path} is neither a file nor a bundled HDRI; pass an .exr/.hdr file or one "
            f"of: {names}."
        )
    checks.envmap_file("--envmap", path)
