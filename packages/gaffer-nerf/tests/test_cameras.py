"""Cameras: validation (degenerate poses raise clear errors), rays, conversions, pixel footprint."""

import math

import numpy as np
import pytest
import torch

from gaffer_envmap import C2WOpenCV, orbit_w2c_blender
from gaffer_nerf.cameras import Cameras
from gaffer_nerf.errors import CameraError, ShapeError
from gaffer_nerf.testing import orbit_cameras


def _cams(c2w: torch.Tensor, f: float = 50.0) -> Cameras:
    v = c2w.shape[0]
    return Cameras(
        c2w_opencv=c2w,
        focal_px=torch.full((v, 2), f),
        principal_px=torch.full((v, 2), 8.0),
        width=16,
        height=16,
    )


def test_rays_of_identity_camera_look_along_plus_z() -> None:
    rays = _cams(torch.eye(4)[None]).rays()
    assert len(rays) == 256
    torch.testing.assert_close(rays.dirs_world.norm(dim=-1), torch.ones(256))
    centre = rays.dirs_world.mean(dim=0)
    assert centre[2] > 0.99 and abs(float(centre[0])) < 1e-6 and abs(float(centre[1])) < 1e-6
    # row-major: the first pixel is top-left, OpenCV y down -> negative x and y
    assert rays.dirs_world[0, 0] < 0 and rays.dirs_world[0, 1] < 0


def test_w2c_blender_matches_gaffer_envmap() -> None:
    cams = orbit_cameras(4)
    for v in range(4):
        ref = C2WOpenCV(cams.c2w_opencv[v].double().numpy()).to_w2c_blender().matrix
        np.testing.assert_allclose(cams.w2c_blender()[v].numpy(), ref, atol=1e-5)
    # and the orbit camera looks at the origin
    w2c = orbit_w2c_blender(30.0, 20.0, 2.5)
    c2w = torch.from_numpy(w2c.to_c2w_opencv().matrix.copy()).float()[None]
    d = _cams(c2w).rays().dirs_world.mean(dim=0)
    torch.testing.assert_close(
        torch.nn.functional.normalize(d, dim=0), -c2w[0, :3, 3] / 2.5, atol=1e-3, rtol=0
    )


@pytest.mark.parametrize(
    "bad, match",
    [
        ("nan", "NaN/Inf in views \\[1\\]"),
        ("scale", "do not hold a rotation"),
        ("reflect", "do not hold a rotation"),
        ("last_row", "last row"),
    ],
)
def test_degenerate_poses_raise_named_errors(bad: str, match: str) -> None:
    c2w = orbit_cameras(3).c2w_opencv.clone()
    if bad == "nan":
        c2w[1, 0, 3] = float("nan")
    elif bad == "scale":
        c2w[1, :3, :3] *= 2.0
    elif bad == "reflect":
        c2w[1, :3, 0] *= -1.0
    else:
        c2w[1, 3, 0] = 0.5
    with pytest.raises(CameraError, match=match):
        _cams(c2w)


def test_coincident_cameras_and_bad_intrinsics() -> None:
    c2w = torch.eye(4)[None].repeat(5, 1, 1)
    with pytest.raises(CameraError, match="coincide"):
        _cams(c2w).check_baseline()
    orbit_cameras(3).check_baseline()
    with pytest.raises(CameraError, match="focal_px"):
        _cams(torch.eye(4)[None], f=0.0)
    with pytest.raises(ShapeError, match="c2w_opencv"):
        _cams(torch.eye(3)[None])


def test_pixel_footprint() -> None:
    cams = orbit_cameras(2, resolution=64, distance=2.5, fov_deg=40.0)
    fp = cams.pixel_footprint(torch.zeros(3))
    f = 32 / math.tan(math.radians(20))
    torch.testing.assert_close(fp, torch.full((2,), 2.5 / f), atol=1e-5, rtol=1e-5)
    behind = cams.pixel_footprint(
        cams.centers_world[0] * 2
    )  # behind camera 0? no: in front of none
    assert bool(torch.isinf(behind[0]))
