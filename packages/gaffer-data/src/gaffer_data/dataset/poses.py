"""The `cameras.npz` payload: `CameraPoses` and its reader.

A leaf of `gaffer_data.dataset` (numpy and the error types only), so that `schema` (whose
`RenderedObject.poses()` reads it) and `reader` both import it at the top without an import cycle.
"""

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gaffer_data.errors import IntegrityError


@dataclass(frozen=True)
class CameraPoses:
    """Per-view camera matrices of an object (the `cameras.npz` payload).

    Attributes:
        w2c_blender: `[V, 3, 4]` float64 world-to-camera, Blender camera axes (x right, y up, -z forward).
        c2w_opencv: `[V, 4, 4]` float64 camera-to-world, OpenCV camera axes (x right, y down, z forward).
        intrinsics: `[3, 3]` float64 OpenCV K matrix, shared by all views.
    """

    w2c_blender: np.ndarray
    c2w_opencv: np.ndarray
    intrinsics: np.ndarray


def load_poses(path: Path, num_views: int | None = None) -> CameraPoses:
    """Load a `cameras.npz` payload.

    Args:
        path: the NPZ file.
        num_views: expected V, or None to accept any.

    Raises:
        IntegrityError: missing file, missing key or wrong shapes.
    """
    try:
        with np.load(path, allow_pickle=False) as npz:
            w2c = np.array(npz["w2c_blender"], dtype=np.float64)
            c2w = np.array(npz["c2w_opencv"], dtype=np.float64)
            k = np.array(npz["intrinsics"], dtype=np.float64)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise IntegrityError(
            f"`{path}` is not a valid cameras NPZ ({exc!r}); re-render the object."
        ) from exc
    v = w2c.shape[0] if num_views is None else num_views
    if w2c.shape != (v, 3, 4) or c2w.shape != (v, 4, 4) or k.shape != (3, 3):
        raise IntegrityError(
            f"`{path}` holds w2c_blender {w2c.shape}, c2w_opencv {c2w.shape}, intrinsics {k.shape}; "
            f"expected ({v}, 3, 4), ({v}, 4, 4), (3, 3)."
        )
    for arr in (w2c, c2w, k):
        arr.flags.writeable = False
    return CameraPoses(w2c_blender=w2c, c2w_opencv=c2w, intrinsics=k)
