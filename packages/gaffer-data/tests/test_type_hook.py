"""Canary: the jaxtyping + beartype import hook is on for `gaffer_data` in these tests.

The root pyproject's pytest `addopts` pass `--jaxtyping-packages=...,gaffer_data,...,beartype.beartype`;
jaxtyping's pytest plugin installs the hook before any conftest or test module runs, so `gaffer_data`
is instrumented however the run imports it. Each call below works, or fails differently, without the hook.
"""

import jaxtyping
import pytest

from gaffer_data.config import MultiviewConfig
from gaffer_data.dataset.manifest import plan_from_json
from gaffer_data.dataset.schema import CameraSample, Intrinsics
from gaffer_data.filter.rules import FilterRules
from gaffer_data.render.plan import camera_position, plan_object, poses_from_c2w_blender


def test_a_wrong_shape_is_refused_by_the_hook() -> None:
    # `position: tuple[float, float, float]`; without the hook the record is built with two numbers.
    with pytest.raises(jaxtyping.TypeCheckError, match="position"):
        CameraSample(elevation_deg=0.0, azimuth_deg=0.0, distance=2.0, position=(0.0, 2.0))  # type: ignore[arg-type]


def test_a_wrong_type_is_refused_by_the_hook() -> None:
    # `c2w_blender: np.ndarray`; without the hook `np.asarray` would take the nested lists (and the
    # identity pose would stack).
    intrinsics = Intrinsics(width=8, height=8, fx=8.0, fy=8.0, cx=4.0, cy=4.0)
    eye = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    with pytest.raises(jaxtyping.TypeCheckError, match=r"parameter .c2w_blender."):
        poses_from_c2w_blender([eye], intrinsics)  # type: ignore[arg-type]


def test_every_module_is_instrumented() -> None:
    # The hook wraps each function of each `gaffer_data` module (`functools.wraps` leaves `__wrapped__`).
    functions = (
        camera_position,
        plan_object,
        poses_from_c2w_blender,
        plan_from_json,
        FilterRules.evaluate,
    )
    assert [f.__qualname__ for f in functions if not hasattr(f, "__wrapped__")] == []
    # and checks each dataclass's `__init__` (the elevation band is a pair).
    with pytest.raises(jaxtyping.TypeCheckError, match="elevation_deg"):
        MultiviewConfig(elevation_deg=(0.0, 45.0, 90.0))  # type: ignore[arg-type]
