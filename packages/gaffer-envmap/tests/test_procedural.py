"""Procedural HDR environment maps (`gaffer_envmap.procedural.procedural_envmap`)."""

import numpy as np
import pytest

import gaffer_envmap
from gaffer_envmap import EnvironmentMap
from gaffer_envmap.procedural import procedural_envmap

SEEDS = range(48)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def test_same_seed_same_map_and_different_seeds_differ() -> None:
    a = procedural_envmap(7, height=32)
    b = procedural_envmap(7, height=32)
    np.testing.assert_array_equal(a.radiance_linear, b.radiance_linear)
    maps = [procedural_envmap(s, height=32).radiance_linear for s in range(8)]
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


def test_bad_arguments_raise_value_error() -> None:
    with pytest.raises(ValueError, match="seed"):
        procedural_envmap(-1)
    with pytest.raises(ValueError, match="height"):
        procedural_envmap(0, height=7)
    with pytest.raises(ValueError, match="height"):
        procedural_envmap(0, height=0)
    procedural_envmap(0, height=8)  # the smallest allowed


def test_exported_from_the_package() -> None:
    assert gaffer_envmap.procedural_envmap is procedural_envmap
    assert "procedural_envmap" in gaffer_envmap.__all__
    assert "procedural_envmap" in dir(gaffer_envmap)
