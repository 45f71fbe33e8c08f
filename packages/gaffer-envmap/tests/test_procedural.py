"""Procedural HDR environment maps (`gaffer_envmap.procedural.procedural_envmap`; the seeding, argument and export tests
also cover `gaffer_envmap.procedural_physical.physical_envmap`)."""

import importlib
from collections.abc import Callable

import numpy as np
import pytest

import gaffer_envmap
from gaffer_envmap import EnvironmentMap
from gaffer_envmap.procedural import procedural_envmap
from gaffer_envmap.procedural_physical import physical_envmap

SEEDS = range(48)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


@pytest.mark.parametrize("make", [procedural_envmap, physical_envmap])
def test_same_seed_same_map_and_different_seeds_differ(make: Callable[..., EnvironmentMap]) -> None:
    a = make(7, height=32)
    b = make(7, height=32)
    np.testing.assert_array_equal(a.radiance_linear, b.radiance_linear)
    maps = [make(s, height=32).radiance_linear for s in range(8)]
    for i in range(len(maps)):
        for j in range(i + 1, len(maps)):
            assert not np.allclose(maps[i], maps[j], rtol=1e-3), (i, j)


@pytest.mark.parametrize("height", [8, 16, 33, 128])
def test_shape_dtype_and_metadata(height: int) -> None:
    env = procedural_envmap(3, height=height)
    assert isinstance(env, EnvironmentMap)
    assert env.radiance_linear.shape == (height, 2 * height, 3)
    assert env.radiance_linear.dtype == np.float32
    assert env.metadata["gaffer:procedural_seed"] == "3"
    assert procedural_envmap(3).radiance_linear.shape == (128, 256, 3)  # the default height


def test_radiance_is_finite_non_negative_hdr_with_a_plausible_mean() -> None:
    sky_above_ground = 0
    for seed in SEEDS:
        e = procedural_envmap(seed, height=32).radiance_linear
        assert np.isfinite(e).all(), seed
        assert (e >= 0).all(), seed
        mean = float(e.mean())
        assert 0.05 <= mean <= 2.0, (seed, mean)
        # the emitters stand out of the sky: a high dynamic range
        assert float(e.max()) > 2.0 * mean, seed
        lum = e @ _LUMA
        h = e.shape[0]
        sky_above_ground += int(np.median(lum[: h // 2]) > np.median(lum[h // 2 :]))
    # z up: the sky (upper rows) is brighter than the ground on (nearly) every map
    assert sky_above_ground >= 0.9 * len(SEEDS)


@pytest.mark.parametrize("make", [procedural_envmap, physical_envmap])
def test_bad_arguments_raise_value_error(make: Callable[..., EnvironmentMap]) -> None:
    with pytest.raises(ValueError, match="seed"):
        make(-1)
    with pytest.raises(ValueError, match="height"):
        make(0, height=7)
    with pytest.raises(ValueError, match="height"):
        make(0, height=0)
    make(0, height=8)  # the smallest allowed


@pytest.mark.parametrize("name", ["procedural_envmap", "physical_envmap"])
def test_exported_from_the_package(name: str) -> None:
    module = {"procedural_envmap": "procedural", "physical_envmap": "procedural_physical"}[name]
    assert getattr(gaffer_envmap, name) is getattr(
        importlib.import_module(f"gaffer_envmap.{module}"), name
    )
    assert name in gaffer_envmap.__all__
    assert name in dir(gaffer_envmap)
