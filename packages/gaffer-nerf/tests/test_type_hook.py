"""Canary: the jaxtyping + beartype import hook is on for `gaffer_nerf` in these tests.

The root pyproject's pytest `addopts` pass `--jaxtyping-packages=...,gaffer_nerf,...,beartype.beartype`;
jaxtyping's pytest plugin installs the hook before any conftest or test module runs, so `gaffer_nerf`
is instrumented however the run imports it. Each call below works, or fails differently, without the hook.
"""

import jaxtyping
import pytest
import torch

from gaffer_nerf.evaluate import read_images
from gaffer_nerf.fields.tensorf import positional_encoding
from gaffer_nerf.fit import fit_tensorf
from gaffer_nerf.rendering import render_rays
from gaffer_nerf.testing import orbit_cameras


def test_a_wrong_shape_is_refused_by_the_hook() -> None:
    # `center_world: Float[Tensor, " 3"]`; without the hook a 2-vector fails later, in torch.
    with pytest.raises(jaxtyping.TypeCheckError, match="center_world"):
        orbit_cameras(2).pixel_footprint(torch.zeros(2))


def test_a_wrong_dtype_is_refused_by_the_hook() -> None:
    # `x: Float[Tensor, "N C"]`; without the hook an integer tensor is encoded (as floats).
    with pytest.raises(jaxtyping.TypeCheckError, match="parameter 'x'"):
        positional_encoding(torch.zeros(4, 3, dtype=torch.long), 2)


def test_every_module_is_instrumented() -> None:
    # The hook wraps each function of each `gaffer_nerf` module (`functools.wraps` leaves `__wrapped__`).
    functions = (positional_encoding, read_images, fit_tensorf, render_rays, orbit_cameras)
    assert [f.__qualname__ for f in functions if not hasattr(f, "__wrapped__")] == []
