"""Rotation into the camera frame: exactness, energy, direction, reference twin, bad input."""

import math

import numpy as np
import pytest
import torch

from gaffer_envmap import (
    IDENTITY_LAYOUT_W2C,
    EnvironmentMap,
    PoseError,
    ShapeError,
    W2CBlender,
    first_moment,
    orbit_w2c_blender,
    rotate_to_camera,
    total_power,
    yaw_roll,
)
from gaffer_envmap.testing import (
    angle_deg,
    disc_sun_map,
    reference_rotate,
    relative_rms,
    smooth_random_map,
)


def _rz(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _cam(arr: np.ndarray) -> EnvironmentMap:
    return EnvironmentMap(radiance_linear=arr, convention="neural-gaffer-camera")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.mark.parametrize("filt", ["bilinear", "area", "conservative"])
def test_identity_is_exact(rng: np.random.Generator, filt: str) -> None:
    env = (rng.random((32, 64, 3)) ** 3 * 100).astype(np.float32)
    out = rotate_to_camera(env, IDENTITY_LAYOUT_W2C, filter=filt, renormalize=False)
    assert torch.equal(out[0, 0], torch.from_numpy(env))


@pytest.mark.parametrize("filt", ["bilinear", "area", "conservative"])
@pytest.mark.parametrize("k", [1, 5, -7, 64])
def test_yaw_by_whole_pixels_is_a_roll(rng: np.random.Generator, filt: str, k: int) -> None:
    he = 32
    env = rng.random((he, 2 * he, 3)).astype(np.float32)
    # Camera turned by k pixels about world up: the lookup turns by -alpha, columns move left by k.
    pose = np.concatenate(
        [IDENTITY_LAYOUT_W2C.rotation @ _rz(360.0 * k / (2 * he)), np.zeros((3, 1))], 1
    )
    out = rotate_to_camera(env, pose, filter=filt, renormalize=False)[0, 0].numpy()
    assert np.array_equal(out, np.roll(env, -k, axis=1))


@pytest.mark.parametrize("step", [1, 3])
def test_spin_matches_yaw_augmentation(rng: np.random.Generator, step: int) -> None:
    env = EnvironmentMap(radiance_linear=rng.random((16, 32, 3)).astype(np.float32))
    out = rotate_to_camera(env, IDENTITY_LAYOUT_W2C, filter="bilinear", spin_deg=360.0 * step / 8)
    assert np.array_equal(out[0, 0].numpy(), yaw_roll(env, step, 8).radiance_linear)


def test_full_turn_is_identity(rng: np.random.Generator) -> None:
    env = rng.random((16, 32, 3)).astype(np.float32)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    # A rotation by 2pi built numerically (Rodrigues), composed with the identity layout.
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    full = np.eye(3) + math.sin(2 * math.pi) * k + (1 - math.cos(2 * math.pi)) * k @ k
    out = rotate_to_camera(env, IDENTITY_LAYOUT_W2C.rotation @ full, filter="bilinear")[
        0, 0
    ].numpy()
    assert relative_rms(out, env) < 1e-5


def test_matches_plain_numpy_twin(rng: np.random.Generator) -> None:
    env = smooth_random_map(32, seed=3).radiance_linear
    for _ in range(3):
        r = _random_rotation(rng)
        fast = rotate_to_camera(env, r, height=24, width=40, filter="bilinear")[0, 0].numpy()
        ref = reference_rotate(env, r, 24, 40)
        assert np.abs(fast - ref).max() < 1e-4 * np.abs(ref).max()


def test_seam_and_poles_are_continuous() -> None:
    """A smooth map stays smooth after half-pixel yaws and pole-crossing rotations (no zero padding)."""
    env = smooth_random_map(32, seed=5)
    for pose in (
        IDENTITY_LAYOUT_W2C.rotation @ _rz(360 / 64 / 2),
        orbit_w2c_blender(10, 89.9).rotation,
    ):
        out = rotate_to_camera(env, pose, filter="bilinear")[0, 0].numpy()
        ref = reference_rotate(env.radiance_linear, pose, 32, 64)
        assert relative_rms(out, ref) < 1e-5
        assert out.min() > 0.04  # zero padding would leave black seams/poles


@pytest.mark.parametrize("trial", range(6))
def test_disc_sun_power_and_direction(trial: int) -> None:
    rng = np.random.default_rng(100 + trial)
    sun = rng.normal(size=3)
    sun /= np.linalg.norm(sun)
    env = disc_sun_map(64, sun, radius_deg=rng.uniform(1.0, 3.0), radiance=1000.0, sky=0.0)
    r = _random_rotation(rng)
    p_in = total_power(env)
    out = rotate_to_camera(env, r, height=32, filter="area", supersample=2, renormalize=True)[
        0, 0
    ].numpy()
    p_out = total_power(_cam(out))
    np.testing.assert_allclose(p_out, p_in, rtol=1e-6)
    m = first_moment(_cam(out))
    assert angle_deg(m, r @ sun) < 0.5 * 180 / 32  # half an output pixel


def test_supersampling_reduces_unnormalised_power_error() -> None:
    """Without renormalisation a small sun is partly missed by the sub-samples; more sub-samples, less error."""
    errors: dict[int, list[float]] = {1: [], 4: []}
    for trial in range(10):
        rng = np.random.default_rng(100 + trial)
        sun = rng.normal(size=3)
        env = disc_sun_map(
            64, sun / np.linalg.norm(sun), radius_deg=rng.uniform(1.0, 3.0), radiance=1000.0
        )
        r = _random_rotation(rng)
        for ss in errors:
            out = rotate_to_camera(
                env, r, height=32, filter="area", supersample=ss, renormalize=False
            )[0, 0].numpy()
            errors[ss].append(abs(total_power(_cam(out))[0] / total_power(env)[0] - 1))
    assert np.median(errors[4]) < 0.02
    assert np.mean(errors[4]) < 0.5 * np.mean(errors[1])


def test_first_moment_rotates_with_the_camera(rng: np.random.Generator) -> None:
    env = smooth_random_map(48, seed=7)
    for _ in range(3):
        r = _random_rotation(rng)
        out = rotate_to_camera(env, r, filter="area", supersample=3)[0, 0].numpy()
        assert angle_deg(first_moment(_cam(out)), r @ first_moment(env)) < 0.2


def test_inverse_rotation_recovers_band_limited_map(rng: np.random.Generator) -> None:
    env = smooth_random_map(64, seed=9)
    r = _random_rotation(rng)
    cam = rotate_to_camera(env, r, filter="bilinear")[0, 0].numpy()
    # Back to the world: the camera map in the identity layout's frame, rotated by R^T.
    back = rotate_to_camera(
        cam, IDENTITY_LAYOUT_W2C.rotation @ r.T @ IDENTITY_LAYOUT_W2C.rotation, filter="bilinear"
    )
    assert relative_rms(back[0, 0].numpy(), env.radiance_linear) < 0.01


def test_batched_outer_and_zip_agree_with_single_calls(rng: np.random.Generator) -> None:
    maps = rng.random((3, 8, 16, 3)).astype(np.float32)
    poses = [orbit_w2c_blender(a, e) for a, e in ((0, 0), (45, 30), (200, -60))]
    outer = rotate_to_camera(maps, poses, height=6, width=10)
    zipped = rotate_to_camera(maps, poses, height=6, width=10, pairing="zip")
    assert outer.shape == (3, 3, 6, 10, 3) and zipped.shape == (3, 6, 10, 3)
    for i in range(3):
        single = rotate_to_camera(maps[i], poses[i], height=6, width=10)[0, 0]
        torch.testing.assert_close(zipped[i], single)
        torch.testing.assert_close(outer[i, i], single)


def test_nan_neighbours_do_not_leak_into_exact_samples() -> None:
    env = np.ones((8, 16, 3), np.float32)
    env[0, 0] = np.inf
    out = rotate_to_camera(env, IDENTITY_LAYOUT_W2C, filter="bilinear")[0, 0].numpy()
    assert np.isinf(out[0, 0]).all() and np.isfinite(out[1:]).all()


def test_bad_inputs_raise_named_errors() -> None:
    env = np.ones((8, 16, 3), np.float32)
    with pytest.raises(PoseError, match="not a rotation"):
        rotate_to_camera(env, np.diag([2.0, 1, 1]))
    with pytest.raises(PoseError, match="determinant"):
        rotate_to_camera(env, np.diag([1.0, 1, -1]))
    with pytest.raises(PoseError, match="shape"):
        rotate_to_camera(env, np.eye(2))
    with pytest.raises(ShapeError):
        rotate_to_camera(np.ones((8, 8, 3), np.float32), np.eye(3))
    with pytest.raises(ShapeError, match="one pose per map"):
        rotate_to_camera(
            np.ones((2, 8, 16, 3), np.float32), np.eye(3)[None].repeat(3, 0), pairing="zip"
        )
    with pytest.raises(PoseError, match="NaN"):
        W2CBlender(np.full((3, 4), np.nan))
