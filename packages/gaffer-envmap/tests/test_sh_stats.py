"""Spherical harmonics invariants, irradiance against brute force, map statistics."""

import math

import numpy as np
import pytest

from gaffer_envmap import EnvironmentMap, describe, project_sh, rotate_to_camera, sh_basis
from gaffer_envmap.poses import IDENTITY_LAYOUT_W2C
from gaffer_envmap.sh import cosine_lobe_coefficients, irradiance, irradiance_brute_force
from gaffer_envmap.testing import disc_sun_map, smooth_random_map


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def test_basis_is_orthonormal_on_a_fine_grid() -> None:
    from gaffer_envmap.conventions import direction_grid, row_solid_angle

    dirs = direction_grid(256, 512)
    om = row_solid_angle(256)
    b = sh_basis(dirs, 4)
    gram = np.einsum("hwk,hwl,h->kl", b, b, om)
    np.testing.assert_allclose(gram, np.eye(25), atol=2e-4)


def test_band1_is_y_z_x() -> None:
    d = np.array([[0.3, -0.5, 0.81]])
    d /= np.linalg.norm(d)
    np.testing.assert_allclose(
        sh_basis(d, 1)[0, 1:], math.sqrt(3 / (4 * math.pi)) * d[0, [1, 2, 0]], rtol=1e-12
    )


def test_cosine_lobe_coefficients() -> None:
    np.testing.assert_allclose(
        cosine_lobe_coefficients(4),
        [math.pi, 2 * math.pi / 3, math.pi / 4, 0, -math.pi / 24],
        atol=1e-12,
    )


def test_band_energies_are_rotation_invariant() -> None:
    """l = 0 is invariant; the l = 1 vector rotates with the map; each band's energy is invariant."""
    rng = np.random.default_rng(0)
    env = smooth_random_map(64, seed=1)
    r = _random_rotation(rng)
    # A world-frame rotation of the map: the camera-frame map of pose R0 R, read as a Blender map.
    rotated = rotate_to_camera(env, IDENTITY_LAYOUT_W2C.rotation @ r, filter="area", supersample=3)[
        0, 0
    ].numpy()
    rot_env = EnvironmentMap(radiance_linear=rotated)
    c0, c1 = project_sh(env, 3), project_sh(rot_env, 3)
    np.testing.assert_allclose(c1[0], c0[0], rtol=2e-3)
    v0, v1 = c0[[3, 1, 2], 0], c1[[3, 1, 2], 0]  # (x, y, z) order of band 1
    np.testing.assert_allclose(v1, r @ v0, atol=3e-3 * np.linalg.norm(v0))  # E'(b) = E(r^T b)
    for l in range(4):
        sl = slice(l * l, (l + 1) ** 2)
        np.testing.assert_allclose(np.linalg.norm(c1[sl]), np.linalg.norm(c0[sl]), rtol=2e-2)


def test_irradiance_matches_brute_force_for_smooth_light() -> None:
    env = smooth_random_map(48, seed=3)
    rng = np.random.default_rng(3)
    n = rng.normal(size=(20, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    ref = irradiance_brute_force(env, n)
    np.testing.assert_allclose(irradiance(env, n, order=4), ref, rtol=0.01)
    np.testing.assert_allclose(irradiance(env, n, order=2), ref, rtol=0.05)


def test_irradiance_of_constant_sky_is_pi() -> None:
    env = EnvironmentMap(radiance_linear=np.ones((32, 64, 3), np.float32))
    np.testing.assert_allclose(
        irradiance(env, np.array([[0.0, 0, 1], [1, 0, 0]])), math.pi, rtol=1e-3
    )


def test_describe_reports_power_and_direction() -> None:
    env = disc_sun_map(32, np.array([0.0, 1.0, 0.0]), 4.0, 100.0, sky=0.01)
    raw = env.radiance_linear.copy()
    raw[0, 0, 0] = np.nan
    raw[1, 1, 1] = -1.0
    info = describe(env, raw)
    assert info.nan_count == 1 and info.negative_count == 1 and info.inf_count == 0
    assert info.dominant_direction[1] > 0.99 and info.brightest_pixel_direction[1] > 0.99
    assert info.max_value == pytest.approx(float(env.radiance_linear.max()))


def test_directionality_is_zero_for_a_uniform_sky_and_two_for_a_sun() -> None:
    from gaffer_envmap.sh import directionality

    uniform = EnvironmentMap(radiance_linear=np.full((64, 128, 3), 0.7, np.float32))
    assert directionality(uniform) == pytest.approx(0.0, abs=1e-6)
    # a small sun: the irradiance is max(0, n.d) times its power, whose band-1 / band-0 ratio is 2
    d_sun = np.array([0.3, 0.4, 0.866]) / np.linalg.norm([0.3, 0.4, 0.866])
    sun = disc_sun_map(256, d_sun, radius_deg=2.0, radiance=1e3)
    assert directionality(sun) == pytest.approx(2.0, rel=0.01)
    # a sun over a sky sits between, wherever the sun is
    mixed = disc_sun_map(256, d_sun, radius_deg=2.0, radiance=1e3, sky=0.5)
    d = directionality(mixed)
    assert 0.1 < d < 1.9
    moved = disc_sun_map(256, np.array([-0.8, 0.0, -0.6]), radius_deg=2.0, radiance=1e3, sky=0.5)
    assert directionality(moved) == pytest.approx(d, rel=0.01)
    # spinning about up moves only the horizontal part: a sun at the zenith gives a turntable nothing
    zenith = disc_sun_map(256, np.array([0.0, 0.0, 1.0]), radius_deg=2.0, radiance=1e3)
    assert directionality(zenith) == pytest.approx(2.0, rel=0.01)
    assert directionality(zenith, about_up=True) == pytest.approx(0.0, abs=1e-3)
    horizon = disc_sun_map(256, np.array([1.0, 0.0, 0.0]), radius_deg=2.0, radiance=1e3)
    assert directionality(horizon, about_up=True) == pytest.approx(2.0, rel=0.01)


def test_reconstruct_sh_inverts_project_sh_on_a_band_limited_map() -> None:
    # a known order-2 signal (9 coefficients per channel) drawn on the map's own grid: projecting it
    # recovers the coefficients, and reconstructing them gives back the map, up to quadrature error
    from gaffer_envmap.conventions import direction_grid
    from gaffer_envmap.sh import reconstruct_sh

    rng = np.random.default_rng(3)
    coeffs = rng.normal(size=(9, 3))
    coeffs[0] = 4.0  # keep the radiance positive-ish like a real map; the test does not need it
    dirs = direction_grid(128, 256)
    radiance = reconstruct_sh(coeffs, dirs)
    assert radiance.shape == (128, 256, 3)
    # the direct sum over the basis, independently of reconstruct_sh's order inference
    np.testing.assert_allclose(radiance, np.einsum("hwk,kc->hwc", sh_basis(dirs, 2), coeffs))
    env = EnvironmentMap(radiance_linear=radiance.astype(np.float32))
    back = project_sh(env, 2)
    np.testing.assert_allclose(back, coeffs, atol=2e-3)
    np.testing.assert_allclose(reconstruct_sh(back, dirs), radiance, atol=1e-2)
    # a single band-1 coefficient (index 1: y) is sqrt(3 / 4 pi) times the direction's y
    one = np.zeros((4, 3))
    one[1] = 1.0
    d = np.array([[0.6, 0.8, 0.0]])
    np.testing.assert_allclose(reconstruct_sh(one, d)[0], math.sqrt(3 / (4 * math.pi)) * 0.8)
