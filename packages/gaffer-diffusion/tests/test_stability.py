"""Where the pipeline could break: each case gives finite images or a clear error."""

import numpy as np
import pytest
import torch

from gaffer_diffusion import (
    InputValueError,
    LightingMaps,
    RelightingConditions,
    RelightPipeline,
    RuntimeConfig,
    SamplingConfig,
    lighting_from_envmap,
)
from gaffer_diffusion.testing import random_conditions, tiny_model

pytest.importorskip("gaffer_envmap.encode")
from gaffer_envmap.poses import orbit_w2c_blender

FAST = SamplingConfig(num_inference_steps=2)


def _sun_map(peak: float) -> np.ndarray:
    env = np.full((16, 32, 3), 0.05, np.float32)
    env[4, 10] = peak
    return env


@pytest.mark.parametrize("compat", ["default", "neural-gaffer"])
@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_sun_of_1e5_gives_finite_images(compat, dtype) -> None:
    maps = lighting_from_envmap(_sun_map(1e5), orbit_w2c_blender(20, 10), size=64, compat=compat)
    assert float(maps.hdr.max()) <= 1.0 and float(maps.ldr.max()) <= 1.0
    image = random_conditions(1).image
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype=dtype))
    out = pipe(RelightingConditions(image=image, lighting=maps), FAST, seeds=[0])
    assert torch.isfinite(out.images).all()


def test_all_black_envmap_does_not_divide_by_zero() -> None:
    black = np.zeros((16, 32, 3), np.float32)
    maps = lighting_from_envmap(black, orbit_w2c_blender(0, 0), size=64, compat="default")
    assert torch.isfinite(maps.hdr).all() and float(maps.hdr.max()) == 0.0
    with pytest.warns(UserWarning, match="all-black"):
        compat = lighting_from_envmap(
            black, orbit_w2c_blender(0, 0), size=64, compat="neural-gaffer"
        )
    assert torch.isfinite(compat.hdr).all()
    out = RelightPipeline(tiny_model())(
        RelightingConditions(image=random_conditions(1).image, lighting=maps), FAST, seeds=[0]
    )
    assert torch.isfinite(out.images).all()


def test_nan_and_inf_inputs_are_rejected_with_a_clear_error() -> None:
    x = torch.rand(1, 3, 64, 64)
    bad = x.clone()
    bad[0, 1, 5, 5] = float("inf")
    with pytest.raises(InputValueError, match="`image` holds 1 NaN/Inf"):
        RelightingConditions(image=bad, lighting=LightingMaps(ldr=x, hdr=x))
    with pytest.raises(InputValueError, match="`hdr`"):
        LightingMaps(ldr=x, hdr=bad)


def test_turntable_spin_changes_only_the_lighting() -> None:
    pose = orbit_w2c_blender(20, 10)
    maps = lighting_from_envmap(
        _sun_map(50.0), [pose, pose], size=64, spin_deg=torch.tensor([0.0, 90.0])
    )
    assert maps.batch_size == 2 and not torch.equal(maps.hdr[0], maps.hdr[1])
