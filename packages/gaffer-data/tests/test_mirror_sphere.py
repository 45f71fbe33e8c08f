"""Cycles renders agree with gaffer-envmap's conventions: a mirror sphere reflects where the
camera-frame map ("neural-gaffer-camera", from `rotate_to_camera`) says each light is.

A perfect mirror sphere at the origin is rendered (64 px) under a dark world map with three coloured
discs at known world directions, written in gaffer-envmap's "blender" lat-long convention. For every
sphere pixel we trace the camera ray, reflect it about the sphere normal, express the reflected
direction in the Blender camera frame and look it up in `rotate_to_camera(env, pose)` through
`uv_to_direction` / `direction_to_uv` of the "neural-gaffer-camera" layout. The colour found there must
be the colour Cycles rendered, and each disc's centre must agree within a few degrees. A mirrored or
rotated convention anywhere (world map, Blender's equirect lookup, the camera pose, the camera-frame
layout) fails this test.
"""

import dataclasses
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

if importlib.util.find_spec("bpy") is None:
    pytest.skip("bpy is not installed (gaffer-data[render])", allow_module_level=True)
torch = pytest.importorskip("torch")

from gaffer_data.config import AugmentConfig  # noqa: E402
from gaffer_data.dataset.schema import CameraSample  # noqa: E402
from gaffer_data.render.plan import camera_position, plan_object, plan_poses, scan_envmaps  # noqa: E402
from gaffer_data.render.runner import PLAN_NAME, _prepare_folder  # noqa: E402
from gaffer_data.testing import read_exr, tiny_config, write_exr, write_mirror_sphere_obj  # noqa: E402
from gaffer_envmap.conventions import direction_grid, direction_to_uv, uv_to_direction  # noqa: E402
from gaffer_envmap.environment_map import EnvironmentMap  # noqa: E402
from gaffer_envmap.poses import orbit_w2c_blender  # noqa: E402
from gaffer_envmap.rotate import rotate_to_camera  # noqa: E402

pytestmark = pytest.mark.blender

AZIMUTH, ELEVATION, DISTANCE = 40.0, 25.0, 2.0
RESOLUTION = 64
DISC_RADIUS_DEG = 14.0
COLOURS = np.eye(3) * 8.0  # red, green, blue discs of radiance 8 on a 0.02 grey world


def _rotate(v: np.ndarray, axis: np.ndarray, deg: float) -> np.ndarray:
    """Rodrigues rotation of `v` about unit `axis` by `deg` degrees."""
    a = np.deg2rad(deg)
    return v * np.cos(a) + np.cross(axis, v) * np.sin(a) + axis * (axis @ v) * (1 - np.cos(a))


def _disc_directions(w2c: np.ndarray) -> np.ndarray:
    """Three world directions around the camera direction, asymmetric, so a mirror error shows."""
    right, up = w2c[0, :3], w2c[1, :3]
    to_camera = w2c[2, :3]  # Blender camera +z points back towards the camera
    return np.stack(
        [
            _rotate(to_camera, up, 55.0),  # swings towards camera right
            _rotate(to_camera, -right, 45.0),  # towards camera up
            _rotate(_rotate(to_camera, -up, 60.0), right, 30.0),  # left and down
        ]
    )


def _world_map(discs: np.ndarray, height: int = 64) -> np.ndarray:
    dirs = direction_grid(height, 2 * height, "blender")  # [He, We, 3] world directions
    rgb = np.full((height, 2 * height, 3), 0.02, np.float32)
    for k, d in enumerate(discs):
        rgb[dirs @ d > np.cos(np.deg2rad(DISC_RADIUS_DEG))] = COLOURS[k]
    return rgb


def _classify(rgb: np.ndarray) -> np.ndarray:
    """Disc index per pixel (0, 1, 2) or -1 for the background."""
    label = np.argmax(rgb, axis=-1)
    return np.where(rgb.max(axis=-1) > 1.0, label, -1)


def test_mirror_sphere_reflects_what_the_camera_frame_map_says(tmp_path: Path) -> None:
    pose = orbit_w2c_blender(AZIMUTH, ELEVATION, DISTANCE)
    w2c = pose.matrix  # [3, 4] world -> Blender camera
    discs = _disc_directions(w2c)
    env_rgb = _world_map(discs)
    write_exr(tmp_path / "envmaps" / "discs.exr", env_rgb)
    write_mirror_sphere_obj(tmp_path / "objects" / "mirror.obj")

    config = tiny_config(
        views=1,
        lightings=1,
        resolution=RESOLUTION,
        samples=4,
        area_light_render=False,
        augment=AugmentConfig(flip=False, yaw_steps=1),
    )
    plan = plan_object(
        "mirror", tmp_path / "objects" / "mirror.obj", scan_envmaps(tmp_path / "envmaps"), config
    )
    camera = CameraSample(
        elevation_deg=ELEVATION,
        azimuth_deg=AZIMUTH,
        distance=DISTANCE,
        position=tuple(float(c) for c in camera_position(ELEVATION, AZIMUTH, DISTANCE)),  # type: ignore[arg-type]
    )
    plan = dataclasses.replace(plan, views=(dataclasses.replace(plan.views[0], camera=camera),))
    # The worker places its camera exactly where gaffer-envmap's orbit pose says.
    np.testing.assert_allclose(plan_poses(plan).w2c_blender[0], w2c, atol=1e-9)

    root = tmp_path / "render"
    _prepare_folder(plan, root)
    result = subprocess.run(
        [sys.executable, "-m", "gaffer_data.render.worker", "--job", str(root / PLAN_NAME)],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    ch = read_exr(root / plan.views[0].lit[0].exr)
    rendered = np.stack([ch["R"], ch["G"], ch["B"]], -1)  # [H, W, 3] linear, premultiplied
    alpha = ch["A"]

    # Trace each pixel centre: Blender camera looks along -z, y up; f in pixels from the 35/32 lens.
    f = 35.0 / 32.0 * RESOLUTION
    i, j = np.mgrid[0:RESOLUTION, 0:RESOLUTION] + 0.5
    d_cam = np.stack([(j - RESOLUTION / 2) / f, -(i - RESOLUTION / 2) / f, -np.ones_like(i)], -1)
    d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
    rot = w2c[:, :3]
    eye = -rot.T @ w2c[:, 3]
    d_world = d_cam @ rot  # rows: R^T d
    radius = 0.5  # the worker scales the scene to a unit bounding box: the sphere's radius is 0.5
    b = d_world @ eye
    disc = b**2 - (eye @ eye - radius**2)
    hit = (disc > 0) & (alpha > 0.999)
    t = -b - np.sqrt(np.where(disc > 0, disc, 0.0))
    normal = (eye + t[..., None] * d_world) / radius
    refl_world = d_world - 2 * np.sum(d_world * normal, -1, keepdims=True) * normal
    refl_cam = refl_world @ rot.T  # [H, W, 3] reflected directions in the Blender camera frame
    # Stay away from the silhouette, where one pixel spans a huge solid angle.
    inner = hit & (np.sum(-d_world * normal, -1) > 0.35)
    assert inner.sum() > 300

    # The camera-frame map of the same world map, and the colour it holds at each reflected direction.
    env = EnvironmentMap(radiance_linear=env_rgb)
    cam_map = rotate_to_camera(env, pose, filter="bilinear")[0, 0].numpy()  # [He, We, 3]
    he, we = cam_map.shape[:2]
    u, v = direction_to_uv(refl_cam[inner], "neural-gaffer-camera")
    looked_up = cam_map[
        np.minimum((v * he).astype(int), he - 1), np.minimum((u * we).astype(int), we - 1)
    ]
    got, want = _classify(rendered[inner]), _classify(looked_up)
    on_a_disc = (got >= 0) | (want >= 0)  # ignore the background, which is most of the sphere
    agree = np.mean(got[on_a_disc] == want[on_a_disc])
    assert agree > 0.8, f"only {agree:.1%} of disc pixels agree with the camera-frame map"

    # Each disc: the centre of its pixels in the camera-frame map (via uv_to_direction) matches the
    # mean reflected direction of the pixels where Cycles shows it.
    uu, vv = np.meshgrid((np.arange(we) + 0.5) / we, (np.arange(he) + 0.5) / he)
    map_dirs = uv_to_direction(uu, vv, "neural-gaffer-camera")
    weights = np.sin(np.pi * vv)  # solid angle of a lat-long pixel
    map_labels = _classify(cam_map)
    for k in range(3):
        assert (got == k).sum() >= 4, f"disc {k} is not visible in the mirror"
        centre_map = (map_dirs[map_labels == k] * weights[map_labels == k, None]).sum(0)
        centre_render = refl_cam[inner][got == k].mean(0)
        # The disc's true direction, rotated into the camera frame by the pose.
        centre_true = rot @ discs[k]
        for name, c in (("camera-frame map", centre_map), ("render", centre_render)):
            c = c / np.linalg.norm(c)
            err = np.rad2deg(np.arccos(np.clip(c @ centre_true, -1, 1)))
            assert err < 4.0, f"disc {k}: {name} centre is {err:.1f} deg off"
