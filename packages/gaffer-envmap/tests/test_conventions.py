"""Convention fingerprints (reference table 2.1), round trips, solid angles and exact conversions."""

import numpy as np
import pytest

from gaffer_envmap import (
    CONVENTIONS,
    ConventionError,
    EnvironmentMap,
    ShapeError,
    chirality,
    convert_convention,
    direction_to_uv,
    row_solid_angle,
    solid_angle,
    to_center_alignment,
    uv_to_direction,
)

X, Y, Z = np.eye(3)
# name: (up, dir at u=0, u=.25, u=.5, u=.75, chirality), each in the convention's own world frame.
FINGERPRINTS = {
    "blender": (Z, -X, Y, X, -Y, -1),
    "neural-gaffer-camera": (Y, -X, -Z, X, Z, -1),
    "threejs": (Y, -X, -Z, X, Z, -1),
    "mitsuba": (Y, -Z, X, Z, -X, -1),
    "openexr": (Y, -Z, X, Z, -X, -1),
    "usd": (Y, -Z, X, Z, -X, -1),
    "skylibs": (Y, Z, -X, -Z, X, -1),
    "nvdiffrec": (Y, Z, -X, -Z, X, -1),
    "filament": (Y, -Z, -X, Z, X, 1),
    "pbrt-v3": (Z, X, Y, -X, -Y, 1),
}


@pytest.mark.parametrize("name", sorted(FINGERPRINTS))
def test_fingerprint(name: str) -> None:
    up, *horizon, chir = FINGERPRINTS[name]
    for u, expected in zip((0.0, 0.25, 0.5, 0.75), horizon, strict=True):
        got = uv_to_direction(np.array(u), np.array(0.5), name)
        np.testing.assert_allclose(got, expected, atol=1e-12, err_msg=f"{name} u={u}")
    np.testing.assert_allclose(uv_to_direction(np.array(0.3), np.array(0.0), name), up, atol=1e-12)
    np.testing.assert_allclose(uv_to_direction(np.array(0.3), np.array(1.0), name), -up, atol=1e-12)
    assert chirality(name) == chir


def test_every_registered_convention_has_a_fingerprint() -> None:
    assert set(CONVENTIONS) == set(FINGERPRINTS)


@pytest.mark.parametrize("name", sorted(CONVENTIONS))
def test_direction_uv_round_trip(name: str) -> None:
    rng = np.random.default_rng(0)
    u, v = rng.uniform(0, 1, 1000), rng.uniform(0.001, 0.999, 1000)
    d = uv_to_direction(u, v, name)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
    u2, v2 = direction_to_uv(d, name)
    du = np.abs((u2 - u + 0.5) % 1.0 - 0.5)
    assert du.max() < 1e-9 and np.abs(v2 - v).max() < 1e-9


def test_blender_formula_matches_cycles_source() -> None:
    # Cycles direction_to_equirectangular: u = 0.5 - atan2(y, x) / 2pi, v_top_down = acos(z) / pi.
    rng = np.random.default_rng(1)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u, v = direction_to_uv(d, "blender")
    np.testing.assert_allclose(
        u, np.mod(0.5 - np.arctan2(d[:, 1], d[:, 0]) / (2 * np.pi), 1), atol=1e-12
    )
    np.testing.assert_allclose(v, np.arccos(d[:, 2]) / np.pi, atol=1e-12)


@pytest.mark.parametrize("alignment", ["center", "corner"])
@pytest.mark.parametrize("height", [1, 2, 7, 64])
def test_solid_angles_sum_to_4pi(height: int, alignment: str) -> None:
    if alignment == "corner" and height < 2:
        pytest.skip("a corner-aligned grid needs two rows")
    total = solid_angle(height, 2 * height, alignment).sum()  # type: ignore[arg-type]
    assert abs(total - 4 * np.pi) < 1e-12


def test_row_solid_angle_is_symmetric_and_largest_at_equator() -> None:
    om = row_solid_angle(32)
    np.testing.assert_allclose(om, om[::-1], rtol=1e-12)
    assert om.argmax() in (15, 16) and om[0] < om[16] / 10


WORLD = ["blender", "threejs", "mitsuba", "skylibs", "filament", "pbrt-v3"]


@pytest.mark.parametrize("src", WORLD)
@pytest.mark.parametrize("dst", WORLD)
def test_conversion_is_exact_and_physical(src: str, dst: str) -> None:
    """A -> B keeps every pixel's physical direction (through Blender's world), bit for bit, and B -> A inverts."""
    rng = np.random.default_rng(2)
    he = 8
    env = EnvironmentMap(
        radiance_linear=rng.random((he, 2 * he, 3), dtype=np.float32), convention=src
    )
    if (
        CONVENTIONS[src].up != CONVENTIONS[dst].up
        and np.dot(
            np.asarray(CONVENTIONS[src].to_blender) @ CONVENTIONS[src].up,
            np.asarray(CONVENTIONS[dst].to_blender) @ CONVENTIONS[dst].up,
        )
        < 0.5
    ):
        pytest.skip("different up axes")
    out = convert_convention(env, dst)
    assert out.convention == dst
    back = convert_convention(out, src)
    assert np.array_equal(back.radiance_linear, env.radiance_linear)
    # Physical check: dst pixel (i, j) direction, mapped to src frame, lands on the src pixel holding that value.
    i, j = 3, 5
    d_dst = uv_to_direction(np.array((j + 0.5) / (2 * he)), np.array((i + 0.5) / he), dst)
    to_b = lambda name: np.asarray(CONVENTIONS[name].to_blender)  # noqa: E731
    d_src = to_b(src).T @ (to_b(dst) @ d_dst)
    us, vs = direction_to_uv(d_src, src)
    js, is_ = int(np.floor(us * 2 * he)), int(np.floor(vs * he))
    assert np.array_equal(out.radiance_linear[i, j], env.radiance_linear[is_, js])


def test_conversion_refuses_camera_frame_and_odd_widths() -> None:
    env = EnvironmentMap(radiance_linear=np.zeros((3, 6, 3), np.float32))
    with pytest.raises(ConventionError, match="rotate_to_camera"):
        convert_convention(env, "neural-gaffer-camera")
    with pytest.raises(ConventionError, match="divisible by 4"):
        convert_convention(env, "skylibs")
    with pytest.raises(ConventionError, match="unknown"):
        convert_convention(env, "photoshop")


def test_corner_alignment_realignment_keeps_smooth_maps() -> None:
    he = 33  # corner grid: rows at both poles
    v = np.arange(he) / (he - 1)
    u = np.arange(2 * (he - 1) + 1) / (2 * (he - 1))
    # A smooth function of direction sampled on the corner grid (width = 2*(He-1)+1 would not be 2:1,
    # so sample the standard corner layout of width 2*He and compare at the realigned centres).
    del u
    width = 2 * he
    uu, vv = np.meshgrid(np.arange(width) / (width - 1), v)
    d = uv_to_direction(uu, vv, "blender")
    corner = EnvironmentMap(radiance_linear=(1.5 + d).astype(np.float32), alignment="corner")
    centre = to_center_alignment(corner)
    assert centre.alignment == "center" and centre.height == he - 1
    u_c, v_c = (
        (np.arange(centre.width) + 0.5) / centre.width,
        (np.arange(centre.height) + 0.5) / centre.height,
    )
    uu, vv = np.meshgrid(u_c, v_c)
    expected = 1.5 + uv_to_direction(uu, vv, "blender")
    assert np.abs(centre.radiance_linear - expected).max() < 5e-3


def test_environment_map_validates_shape() -> None:
    with pytest.raises(ShapeError, match="2:1"):
        EnvironmentMap(radiance_linear=np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ShapeError, match="alpha"):
        EnvironmentMap(radiance_linear=np.zeros((4, 8, 4), np.float32))
    env = EnvironmentMap(radiance_linear=np.zeros((4, 8, 3)))
    assert env.radiance_linear.dtype == np.float32 and not env.radiance_linear.flags.writeable
