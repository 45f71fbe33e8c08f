"""Canary: the jaxtyping + beartype import hook is on for `gaffer_envmap` in these tests.

The root pyproject's pytest `addopts` pass `--jaxtyping-packages=gaffer_envmap,...,beartype.beartype`;
jaxtyping's pytest plugin installs the hook before any conftest or test module runs, so `gaffer_envmap`
is instrumented even when another package's tests import it first (one `pytest` run over the whole
tree, as `nox -s tests` does). Each call below works, or fails differently, without the hook.
"""

import jaxtyping
import numpy as np
import pytest

from gaffer_envmap.conventions import direction_to_uv
from gaffer_envmap.encode import encode_lighting
from gaffer_envmap.io import read_envmap
from gaffer_envmap.poses import look_at_w2c_blender, orbit_w2c_blender
from gaffer_envmap.rotate import rotate_to_camera
from gaffer_envmap.sanitize import sanitize


def test_a_wrong_shape_is_refused_by_the_hook() -> None:
    # `target: tuple[float, float, float]`; without the hook numpy fails later, with a ValueError
    # (shapes (2,) and (3,) do not broadcast).
    with pytest.raises(jaxtyping.TypeCheckError, match="target"):
        look_at_w2c_blender(np.array([0.0, -3.0, 1.0]), target=(0.0, 0.0))  # type: ignore[arg-type]


def test_a_wrong_type_is_refused_by_the_hook() -> None:
    # `radiance: np.ndarray`; without the hook `np.asarray` would take the list.
    with pytest.raises(jaxtyping.TypeCheckError, match="radiance"):
        sanitize([1.0, 2.0])  # type: ignore[arg-type]


def test_every_module_is_instrumented() -> None:
    # The hook wraps each function of each `gaffer_envmap` module (`functools.wraps` leaves `__wrapped__`).
    functions = (orbit_w2c_blender, encode_lighting, rotate_to_camera, read_envmap, direction_to_uv)
    assert [f.__qualname__ for f in functions if not hasattr(f, "__wrapped__")] == []
