"""Canary: the jaxtyping + beartype import hook is on for `gaffer_diffusion` in these tests.

The root pyproject's pytest `addopts` pass `--jaxtyping-packages=...,gaffer_diffusion,...,beartype.beartype`;
jaxtyping's pytest plugin installs the hook before any conftest or test module runs, so
`gaffer_diffusion` is instrumented however the run imports it. Each call below works, or fails
differently, without the hook.
"""

import jaxtyping
import numpy as np
import pytest
import torch

from gaffer_diffusion.conditioning import lighting_from_envmap
from gaffer_diffusion.detail_transfer import box_mean
from gaffer_diffusion.evaluation import quantize_8bit
from gaffer_diffusion.metrics import channel_align, psnr
from gaffer_diffusion.photo import model_crop


def test_a_wrong_shape_is_refused_by_the_hook() -> None:
    # `images: Float[Tensor, "B 3 H W"]`; without the hook an unbatched image is quantized as well.
    with pytest.raises(jaxtyping.TypeCheckError, match="images"):
        quantize_8bit(torch.rand(3, 8, 8))
    # `relit: Float[Tensor, "3 S S"]`: the crop must be square.
    with pytest.raises(jaxtyping.TypeCheckError, match="relit"):
        model_crop(torch.rand(3, 8, 4))


def test_a_wrong_dtype_is_refused_by_the_hook() -> None:
    # `x: Float[np.ndarray, "H W *C"]`; without the hook an integer image is filtered too.
    with pytest.raises(jaxtyping.TypeCheckError, match="parameter 'x'"):
        box_mean(np.zeros((4, 4, 3), dtype=np.int64), 1)


def test_every_module_is_instrumented() -> None:
    # The hook wraps each function of each `gaffer_diffusion` module (`functools.wraps` leaves
    # `__wrapped__`).
    functions = (quantize_8bit, box_mean, model_crop, psnr, channel_align, lighting_from_envmap)
    assert [f.__qualname__ for f in functions if not hasattr(f, "__wrapped__")] == []
