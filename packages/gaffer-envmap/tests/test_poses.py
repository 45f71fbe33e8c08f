"""Camera pose types and converters."""

import numpy as np
import pytest

from gaffer_envmap import C2WOpenCV, PoseError, W2CBlender, look_at_w2c_blender, orbit_w2c_blender


def test_orbit_camera_looks_at_origin_with_world_up_up() -> None:
    pose = orbit_w2c_blender(30.0, 20.0, 2.0)
    np.testing.assert_allclose(np.linalg.norm(pose.camera_position_world), 2.0)
    # The origin is straight ahead: on the camera's -z axis.
    origin_cam = pose.matrix @ np.array([0, 0, 0, 1.0])
    np.testing.assert_allclose(origin_cam[:2], 0, atol=1e-12)
    assert origin_cam[2] < 0
    # World up projects to camera +y (no roll).
    up_cam = pose.rotation @ np.array([0, 0, 1.0])
    assert abs(up_cam[0]) < 1e-12 and up_cam[1] > 0


def test_blender_opencv_round_trip_and_axes() -> None:
    pose = orbit_w2c_blender(123.0, -40.0, 1.7)
    c2w = pose.to_c2w_opencv()
    np.testing.assert_allclose(c2w.to_w2c_blender().matrix, pose.matrix, atol=1e-12)
    np.testing.assert_allclose(c2w.matrix[:3, 3], pose.camera_position_world, atol=1e-12)
    # OpenCV +z (viewing direction) points at the origin.
    forward = c2w.matrix[:3, 2]
    np.testing.assert_allclose(forward, -pose.camera_position_world / 1.7, atol=1e-12)


def test_accepts_4x4_and_rejects_bad_matrices() -> None:
    m = np.eye(4)
    m[:3] = orbit_w2c_blender(0, 0).matrix
    assert np.array_equal(W2CBlender.from_array(m).matrix, m[:3])
    bad = m.copy()
    bad[3] = [0, 0, 1, 1]
    with pytest.raises(PoseError, match="last row"):
        W2CBlender.from_array(bad)
    with pytest.raises(PoseError, match="not a rotation"):
        W2CBlender(np.hstack([2 * np.eye(3), np.zeros((3, 1))]))
    with pytest.raises(PoseError, match="shape"):
        C2WOpenCV(np.eye(3))
    with pytest.raises(PoseError, match="equals `target`"):
        look_at_w2c_blender(np.zeros(3))
    with pytest.raises(PoseError, match="distance"):
        orbit_w2c_blender(0, 0, 0)


def test_looking_straight_down_is_defined() -> None:
    pose = orbit_w2c_blender(0.0, 90.0, 2.0)
    assert np.isfinite(pose.matrix).all()
    np.testing.assert_allclose(pose.rotation @ pose.rotation.T, np.eye(3), atol=1e-12)


def test_poses_are_immutable() -> None:
    pose = orbit_w2c_blender(0, 0)
    with pytest.raises(ValueError):
        pose.matrix[0, 0] = 5.0
