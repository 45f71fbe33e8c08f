"""Conservative resize (exact power) and exact flip/yaw augmentation."""

import numpy as np
import pytest
import torch

from gaffer_envmap import (
    AugmentSpec,
    EnvironmentMap,
    GafferEnvmapError,
    augment_pool,
    flip_horizontal,
    mean_light_direction,
    resize_conservative,
    resize_conservative_torch,
    total_power,
    yaw_roll,
)
from gaffer_envmap.testing import angle_deg, disc_sun_map


@pytest.mark.parametrize("h_in,h_out", [(64, 32), (64, 16), (64, 24), (48, 64), (37, 11), (8, 1)])
def test_resize_preserves_power_exactly(h_in: int, h_out: int) -> None:
    rng = np.random.default_rng(h_in * 100 + h_out)
    env = EnvironmentMap(
        radiance_linear=(rng.random((h_in, 2 * h_in, 3)) ** 8 * 1e4).astype(np.float32)
    )
    out = resize_conservative(env, h_out)
    assert out.radiance_linear.shape == (h_out, 2 * h_out, 3)
    np.testing.assert_allclose(total_power(out), total_power(env), rtol=1e-6)


@pytest.mark.parametrize("trial", range(5))
def test_resize_keeps_a_disc_sun_power_and_direction(trial: int) -> None:
    rng = np.random.default_rng(trial)
    sun = rng.normal(size=3)
    sun /= np.linalg.norm(sun)
    env = disc_sun_map(128, sun, radius_deg=rng.uniform(0.3, 1.0), radiance=3e4, sky=0.1)
    out = resize_conservative(env, 32)
    np.testing.assert_allclose(total_power(out), total_power(env), rtol=1e-6)
    assert angle_deg(mean_light_direction(out), mean_light_direction(env)) < 0.5 * 180 / 32


def test_unweighted_box_would_fail_near_the_pole() -> None:
    """The pitfall the solid-angle weights avoid: one bright top-row pixel, 4x box -> power x4 unweighted."""
    env = np.zeros((16, 32, 3), np.float32)
    env[0, 3] = 100.0
    e = EnvironmentMap(radiance_linear=env)
    ours = resize_conservative(e, 4)
    naive = EnvironmentMap(radiance_linear=env.reshape(4, 4, 8, 4, 3).mean((1, 3)))
    assert abs(total_power(ours)[0] / total_power(e)[0] - 1) < 1e-6
    assert total_power(naive)[0] / total_power(e)[0] > 3


def test_resize_batched_torch_and_constant_map() -> None:
    x = torch.ones(2, 3, 16, 32, 3)
    out = resize_conservative_torch(x, 5)
    assert out.shape == (2, 3, 5, 10, 3)
    torch.testing.assert_close(out, torch.ones_like(out))


def test_flip_is_mirror_and_involution() -> None:
    rng = np.random.default_rng(0)
    env = EnvironmentMap(radiance_linear=rng.random((8, 16, 3), dtype=np.float32))
    f = flip_horizontal(env)
    assert np.array_equal(flip_horizontal(f).radiance_linear, env.radiance_linear)
    np.testing.assert_allclose(total_power(f), total_power(env), rtol=1e-12)
    sun = disc_sun_map(32, np.array([0.3, 0.8, 0.5]), 3.0, 100.0)
    d = mean_light_direction(flip_horizontal(sun))
    assert angle_deg(d, [0.3, -0.8, 0.5]) < 0.5  # y -> -y in the Blender world


def test_yaw_is_a_counter_clockwise_turn() -> None:
    sun = disc_sun_map(32, np.array([1.0, 0.0, 0.2]), 3.0, 100.0)
    turned = yaw_roll(sun, 1, 4)  # +90 degrees about +z: +x -> +y
    assert angle_deg(mean_light_direction(turned), [0.0, 1.0, 0.2]) < 0.5
    assert np.array_equal(yaw_roll(sun, 4, 4).radiance_linear, sun.radiance_linear)


def test_augment_pool_is_the_papers_16() -> None:
    env = EnvironmentMap(
        radiance_linear=np.random.default_rng(1).random((8, 16, 3), dtype=np.float32)
    )
    pool = augment_pool(env, flips=True, yaw_steps=8)
    assert len(pool) == 16 and pool[0][0] == AugmentSpec(False, 0, 8)
    assert np.array_equal(pool[0][1].radiance_linear, env.radiance_linear)
    assert len({spec.tag for spec, _ in pool}) == 16
    for _, aug in pool:
        np.testing.assert_allclose(total_power(aug), total_power(env), rtol=1e-12)


def test_yaw_refuses_inexact_steps() -> None:
    env = EnvironmentMap(radiance_linear=np.zeros((3, 6, 3), np.float32))
    with pytest.raises(GafferEnvmapError, match="divide the map width"):
        yaw_roll(env, 1, 4)


def test_mirror_camera_x_negates_camera_x_of_every_pixel() -> None:
    import torch

    from gaffer_envmap.augment import mirror_camera_x
    from gaffer_envmap.conventions import direction_grid
    from gaffer_envmap.errors import GafferEnvmapError

    # a map whose value at each pixel is its own camera-frame direction
    dirs_cam = torch.from_numpy(direction_grid(8, 16, "neural-gaffer-camera")).permute(2, 0, 1)
    mirrored = mirror_camera_x(dirs_cam[None])[0]
    # the mirrored scene's light from d is the original's from (-x, y, z)
    expected = dirs_cam * torch.tensor([-1.0, 1.0, 1.0], dtype=dirs_cam.dtype).view(3, 1, 1)
    torch.testing.assert_close(mirrored, expected)
    assert torch.equal(mirror_camera_x(mirrored[None])[0], dirs_cam)  # an involution
    with pytest.raises(GafferEnvmapError, match="even width"):
        mirror_camera_x(torch.zeros(1, 3, 8, 15))
