"""Our lat-long and camera conventions against what Blender/Cycles actually draws (bpy in a subprocess).

bpy never enters the pytest process (some libraries imported by other tests break it, see
shared/reference/environment.md): each test writes inputs and a JSON job, runs
`sys.executable _blender_scripts/bpy_worker.py job.json`, and compares the EXRs / matrices it writes.

Renders are point samples: Cycles, 1 sample per pixel, box pixel filter of width 0.01 px (every camera
ray leaves through the pixel centre), world = Environment Texture (strength 1), view transform Standard,
32-bit float EXR.

1. World convention ("blender").
   a. Blender's equirectangular panoramic camera is, per the Cycles source (`blender_camera_matrix` in
      intern/cycles/blender/camera.cpp: "make it so environment camera needs to be pointed in the direction
      of the positive x-axis to match an environment texture, this way it is looking at the center of the
      texture") and the manual ("set the camera object rotation to (90, 0, -90)"), laid out like the
      Environment Texture when it looks along world +x with its up = world +z. With Euler XYZ (90, 0, -90)
      the camera axes are x = -Y, y = +Z, z = -X (world). Rendering our synthetic map with that camera must
      give back the map pixel for pixel, and its pixel directions (Cycles formulas below) must equal
      `direction_grid(..., "blender")`.
   b. Independent anchor: perspective cameras (rays fixed by matrix_world alone) looking along each mark's
      world direction see the mark at the image centre, and every pixel equals our bilinear lookup
      (`direction_to_uv(..., "blender")`) along its ray; cameras aimed at the mirror images (y -> -y) don't.
2. Camera poses. A camera placed at the documented orbit position (azimuth counter-clockwise from +x,
   elevation above the horizon) and aimed with a TRACK_TO constraint (track -Z, up Y: the Objaverse/Zero123
   render scripts the paper's data comes from) must have the world-to-camera matrix `orbit_w2c_blender`
   returns, also exactly at elevation +-90, where TRACK_TO keeps following the azimuth.
3. Camera-frame rotation. A panoramic camera at the origin with the rotation of a perspective pose renders
   the world in that camera's frame. Its layout, derived from Cycles (below), is "view direction at the
   centre"; ours ("neural-gaffer-camera") puts camera right at the centre: a pure quarter-turn column roll.
   After that roll the render must equal `rotate_to_camera(env, pose, filter="bilinear")`, except within
   half a row of the source poles, where Cycles' Linear lookup wraps v (blends the top row with the
   BOTTOM row); a model of that wrap reproduces the render everywhere.

Derivation for test 3 (Cycles source, `kernel/camera/projection.h` + `blender/camera.cpp`):
- raster (u, v), v = 0 at the image bottom, default ranges: phi = pi - 2 pi u, theta = pi (1 - v);
  D = (sin t cos p, sin t sin p, cos t) in Cycles' panorama frame.
- That frame is taken to Blender camera-object axes by the fixed matrix rows (0,-1,0), (0,0,1), (-1,0,0):
  d_cam = (-D.y, D.z, -D.x) = (-sin t sin p, cos t, -sin t cos p).
- With image rows stored top first (EXR), theta = pi * v_top. So in the camera frame: top row = +y (up),
  u = 0.5 -> -z (view direction), u = 0.25 -> -x (camera left), u = 0.75 -> +x (right), u = 0 -> +z.
- Ours: u = 0.25 -> -z, u = 0.5 -> +x, u = 0 -> -x, top row = +y. Hence ours(u) = blender(u + 1/4):
  `ours = np.roll(blender_pano, -W // 4, axis=1)`; no flip, no vertical change.
"""

import importlib.util
import json
import math
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from gaffer_envmap.conventions import direction_grid, direction_to_uv, solid_angle
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.poses import W2CBlender, look_at_w2c_blender, orbit_w2c_blender
from gaffer_envmap.rotate import rotate_to_camera


def needs_blender(test: Callable[..., None]) -> Callable[..., None]:
    """Mark a test `blender` and skip it cleanly when bpy is not installed (bpy is never imported here)."""
    test = pytest.mark.skipif(
        importlib.util.find_spec("bpy") is None, reason="needs bpy (gaffer-data[render])"
    )(test)
    return pytest.mark.blender(test)


WORKER = Path(__file__).parent / "_blender_scripts" / "bpy_worker.py"
H, W = 64, 128  # 2.8125 degrees per pixel
PIXEL_DEG = 360.0 / W

# Camera axes (columns) in world coordinates for Euler XYZ (90, 0, -90): x = -Y, y = +Z, z = -X.
WORLD_PANO_ROTATION = np.array([[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# Coloured marks (channel, azimuth deg counter-clockwise from +x seen from above, elevation deg). None lies
# on the x-z plane, so a horizontal flip (y -> -y) moves every one of them.
MARKS = ((0, 30.0, 20.0), (1, 110.0, -30.0), (2, 235.0, 50.0))


def _direction(az_deg: float, el_deg: float) -> np.ndarray:
    az, el = math.radians(az_deg), math.radians(el_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def _synthetic_world(height: int, width: int, *, sharp: bool) -> np.ndarray:
    """`[H, W, 3]` float32 "blender"-convention map: a smooth RGB = 0.5 + 0.4 (x, y, z) gradient (values in
    [0.1, 0.9]) plus, per mark, +4 in its channel: a hard 7-degree disc (`sharp`) or a Gaussian blob
    (sigma 8 degrees)."""
    d = direction_grid(height, width, "blender")
    env = 0.5 + 0.4 * d
    for channel, az, el in MARKS:
        angle = np.degrees(np.arccos(np.clip(d @ _direction(az, el), -1.0, 1.0)))
        bump = (angle < 7.0).astype(float) if sharp else np.exp(-0.5 * (angle / 8.0) ** 2)
        env[..., channel] += 4.0 * bump
    return env.astype(np.float32)


def _mark_direction(
    img: np.ndarray,
    dirs: np.ndarray,
    channel: int,
    *,
    sharp: bool,
    pixel_weight: np.ndarray | None = None,
) -> np.ndarray:
    """Solid-angle-weighted centroid direction of one mark, found without any prior on where it is.

    `dirs`: each pixel's direction; `pixel_weight`: each pixel's solid angle (default: a lat-long grid's)."""
    value = img[..., channel].astype(np.float64)
    weight = (value > 2.0).astype(float) if sharp else np.clip(value - 1.0, 0.0, None)
    if pixel_weight is None:
        pixel_weight = solid_angle(img.shape[0], img.shape[1])
    weight = weight * pixel_weight
    if weight.sum() <= 0:
        return np.full(3, np.nan)
    m = (weight[..., None] * dirs).sum(axis=(0, 1))
    return m / np.linalg.norm(m)


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    if not np.all(np.isfinite(a)):
        return 180.0
    return float(np.degrees(np.arccos(np.clip(a @ b, -1.0, 1.0))))


def _rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.sqrt(np.mean((a - b) ** 2) / np.mean(b**2)))


def _write_exr(path: Path, rgb: np.ndarray) -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, {"RGB": np.ascontiguousarray(rgb, dtype=np.float32)}).write(str(path))


def _read_exr(path: Path) -> np.ndarray:
    channels = OpenEXR.File(str(path), separate_channels=True).channels()
    return np.stack([np.asarray(channels[c].pixels, np.float32) for c in "RGB"], axis=-1)


def _run_worker(tmp_path: Path, job: dict) -> dict:
    job = {**job, "threads": 2, "result": str(tmp_path / "result.json")}
    job_file = tmp_path / "job.json"
    job_file.write_text(json.dumps(job))
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, str(WORKER), str(job_file)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    if proc.returncode != 0:
        raise AssertionError(
            f"bpy worker failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
        )
    result = json.loads((tmp_path / "result.json").read_text())
    result["wall_seconds"] = time.perf_counter() - start
    return result


def _blender_pano_camera_dirs(height: int, width: int) -> np.ndarray:
    """Camera-frame directions of Blender's equirect panorama pixels, from the Cycles formulas (docstring)."""
    u = (np.arange(width) + 0.5) / width
    v_top = (np.arange(height) + 0.5) / height
    phi = (np.pi - 2 * np.pi * u)[None, :]
    theta = (np.pi * v_top)[:, None]
    dx, dy, dz = np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) + 0 * phi
    return np.stack([-dy, dz, -dx], axis=-1)


def _to_ours(blender_pano: np.ndarray) -> np.ndarray:
    """Blender's panorama-in-camera-frame layout -> "neural-gaffer-camera": ours[:, j] = blender[:, j + W/4]."""
    return np.roll(blender_pano, -(blender_pano.shape[1] // 4), axis=1)


def _source_pixel(dirs_world: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Fractional (column, row) in a "blender" map, pixel centres at integers."""
    u, v = direction_to_uv(dirs_world, "blender")
    return u * width - 0.5, v * height - 0.5


def _bilinear_cycles_model(env: np.ndarray, dirs_world: np.ndarray) -> np.ndarray:
    """Bilinear lookup as Cycles' Environment Texture (Linear) does it: periodic in u AND in v, i.e. above
    the top row it blends towards the BOTTOM row (the opposite pole), where the physically right neighbour
    (what rotate_to_camera uses) is the top row turned by half."""
    he, we = env.shape[:2]
    x, y = _source_pixel(dirs_world, he, we)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]

    def at(r: np.ndarray, c: np.ndarray) -> np.ndarray:
        return env[r % he, c % we].astype(np.float64)

    top = at(y0, x0) * (1 - fx) + at(y0, x0 + 1) * fx
    bottom = at(y0 + 1, x0) * (1 - fx) + at(y0 + 1, x0 + 1) * fx
    return top * (1 - fy) + bottom * fy


# --------------------------------------------------------------------------------------------------------
# 1. World convention

PERSP_SIZE, PERSP_FOV_DEG = 32, 40.0  # 1.25 degrees per pixel


def _perspective_dirs(
    size: int, fov_deg: float, c2w_rotation: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World directions `[S, S, 3]` of the pixel-centre rays of a square Blender perspective camera (x right,
    y up, looks along -z; horizontal field of view `fov_deg`), and each pixel's relative solid angle."""
    t = math.tan(math.radians(fov_deg) / 2)
    s = (2 * (np.arange(size) + 0.5) / size - 1) * t
    x, y = np.meshgrid(s, -s)  # row 0 = top of the image = camera +y
    d = np.stack([x, y, -np.ones_like(x)], axis=-1)
    norm = np.linalg.norm(d, axis=-1)
    return (d / norm[..., None]) @ c2w_rotation.T, norm**-3


def _mirror_y(d: np.ndarray) -> np.ndarray:
    return d * np.array([1.0, -1.0, 1.0])


@needs_blender
def test_world_convention_matches_blender_environment_texture(tmp_path: Path) -> None:
    env = _synthetic_world(H, W, sharp=True)
    _write_exr(tmp_path / "env.exr", env)
    renders = [
        {
            "env": str(tmp_path / "env.exr"),
            "out": str(tmp_path / "pano.exr"),
            "width": W,
            "height": H,
            "rotation": WORLD_PANO_ROTATION.tolist(),
            "interpolation": "Closest",
        }
    ]
    # Independent anchor: perspective cameras at the origin looking along each mark's direction (and along
    # its mirror image y -> -y). Their rays are fixed by matrix_world alone, no lat-long convention involved.
    aims = [
        (kind, channel, _direction(az, el) if kind == "at" else _mirror_y(_direction(az, el)))
        for channel, az, el in MARKS
        for kind in ("at", "mirror")
    ]
    # A camera at -aim looking at the origin looks along aim; matrix_world's rotation is the transpose.
    c2ws = [look_at_w2c_blender(-aim).rotation.T for _, _, aim in aims]
    renders += [
        {
            "env": str(tmp_path / "env.exr"),
            "out": str(tmp_path / f"persp{k}.exr"),
            "width": PERSP_SIZE,
            "height": PERSP_SIZE,
            "rotation": c2w.tolist(),
            "interpolation": "Linear",
            "camera": "PERSP",
            "fov_deg": PERSP_FOV_DEG,
        }
        for k, c2w in enumerate(c2ws)
    ]
    result = _run_worker(tmp_path, {"renders": renders})
    info = result["renders"][0]
    assert info["image_is_float"], info
    print(f"world: worker {result['wall_seconds']:.1f} s for {len(renders)} renders")

    # (a) Equirect camera with Euler (90, 0, -90): pixel for pixel the map (Closest interpolation + point
    # samples at pixel centres reproduce the texels).
    pano = _read_exr(tmp_path / "pano.exr")
    assert pano.shape == env.shape
    err = _rel_rms(pano, env)
    print(f"  panorama: rel RMS {err:.3g}, max abs {np.abs(pano - env).max():.3g}")
    assert err < 1e-5
    assert np.abs(pano - env).max() < 1e-4
    # The same camera's pixel directions from the Cycles formulas equal our "blender" grid.
    cycles_world_dirs = _blender_pano_camera_dirs(H, W) @ WORLD_PANO_ROTATION.T
    assert np.abs(cycles_world_dirs - direction_grid(H, W, "blender")).max() < 1e-12
    for channel, az, el in MARKS:
        angle = _angle_deg(
            _mark_direction(pano, cycles_world_dirs, channel, sharp=True), _direction(az, el)
        )
        print(f"  panorama mark {channel} at (az {az}, el {el}): off by {angle:.3f} deg")
        assert angle < 0.5 * PIXEL_DEG

    # (b) Perspective views: every pixel equals the map looked up (bilinear, our direction_to_uv) along
    # its ray, and each mark sits at the image centre.
    for k, ((kind, channel, aim), c2w) in enumerate(zip(aims, c2ws)):
        view = _read_exr(tmp_path / f"persp{k}.exr")
        dirs, pixel_weight = _perspective_dirs(PERSP_SIZE, PERSP_FOV_DEG, c2w)
        model = _bilinear_cycles_model(env, dirs)
        found = _mark_direction(view, dirs, channel, sharp=True, pixel_weight=pixel_weight)
        angle = _angle_deg(found, aim)
        err_view = _rel_rms(view, model)
        print(
            f"  perspective {kind} mark {channel}: rel RMS vs our lookup {err_view:.3g}, "
            f"max abs {np.abs(view - model).max():.3g}, mark off by {angle:.3f} deg"
        )
        assert err_view < 2e-3
        # Negative control: the mirrored map looked up along the same rays does not match.
        assert _rel_rms(view, _bilinear_cycles_model(env[:, ::-1], dirs)) > 0.1
        if kind == "at":
            # The disc is rasterised on 2.8-degree texels: its centroid is good to about half a texel.
            assert angle < 0.5 * PIXEL_DEG
        else:  # looking at the mirror image of a mark: it is out of view (>= 40 deg away)
            assert angle > 10.0

    # Negative controls on the panorama: mirrored (u -> 1 - u, i.e. y -> -y), upside down, a quarter turn.
    assert _rel_rms(pano, env[:, ::-1]) > 0.1
    assert _rel_rms(pano, env[::-1]) > 0.1
    assert _rel_rms(pano, np.roll(env, W // 4, axis=1)) > 0.1


# --------------------------------------------------------------------------------------------------------
# 2. Camera pose convention (TRACK_TO, track -Z, up Y)

# (azimuth, elevation, distance, tolerance). Blender's TRACK_TO works in float32; close to the pole its
# up vector comes from `up - (up . n) n` with up . n ~ 1, so cancellation leaves an error of about the angle to
# the pole (measured 1.6e-4 at 89.99 deg: Blender's own matrix is then orthonormal only to ~1.7e-4).
ORBITS = (
    (0.0, 0.0, 1.5, 1e-5),
    (30.0, 20.0, 2.0, 1e-5),
    (135.0, -35.0, 1.2, 1e-5),
    (250.0, 60.0, 3.0, 1e-5),
    (300.0, 85.0, 1.0, 1e-5),
    (45.0, -80.0, 2.0, 1e-5),
    (200.0, 89.99, 2.0, 5e-4),  # 1.7e-4 rad from the pole: both still follow the azimuth
)


def _w2c_from_matrix_world(matrix_world: np.ndarray) -> np.ndarray:
    m = np.asarray(matrix_world, np.float64)
    return np.linalg.inv(m)[:3]


@needs_blender
def test_track_to_camera_matches_orbit_w2c_blender(tmp_path: Path) -> None:
    poses = [orbit_w2c_blender(az, el, dist) for az, el, dist, _ in ORBITS]
    # Exactly above / below the target (no horizontal offset at all): Blender's roll there.
    poles = [np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, -2.0])]
    # Locations from the documented geometry (azimuth counter-clockwise from +x seen from above, elevation
    # above the horizon), not from the pose under test.
    locations = [(dist * _direction(az, el)).tolist() for az, el, dist, _ in ORBITS] + [
        p.tolist() for p in poles
    ]
    tolerances = [tol for *_, tol in ORBITS] + [1e-5, 1e-5]
    result = _run_worker(tmp_path, {"track_to": [{"location": loc} for loc in locations]})
    got = result["track_to"]
    expected = [p.matrix for p in poses] + [look_at_w2c_blender(p).matrix for p in poles]
    for loc, item, want, tol in zip(locations, got, expected, tolerances):
        w2c = _w2c_from_matrix_world(item["matrix_world"])
        authors = np.asarray(item["rt_authors"])  # the authors' RT derivation gives the same matrix
        err = float(np.abs(w2c - want).max())
        print(f"track-to at {np.round(loc, 4).tolist()}: max |w2c_blender - ours| = {err:.2e}")
        assert err < tol, (loc, w2c, want)
        assert np.abs(authors - want).max() < tol, (loc, authors, want)
        if tol <= 1e-5:
            W2CBlender(w2c)  # a valid rotation in our type

    # Negative controls: the OpenCV camera axes (y, z flipped), the opposite azimuth and the mirrored
    # elevation are all far from what Blender did.
    w2c0 = _w2c_from_matrix_world(got[1]["matrix_world"])
    az, el, dist, _ = ORBITS[1]
    flipped = np.diag([1.0, -1.0, -1.0]) @ poses[1].matrix
    assert np.abs(w2c0 - flipped).max() > 0.5
    assert np.abs(w2c0 - orbit_w2c_blender(-az, el, dist).matrix).max() > 0.5
    assert np.abs(w2c0 - orbit_w2c_blender(az, -el, dist).matrix).max() > 0.5


@needs_blender
def test_track_to_at_the_pole_follows_azimuth(tmp_path: Path) -> None:
    cases = [(45.0, 90.0, 2.0), (200.0, 90.0, 2.0), (45.0, -90.0, 2.0)]
    poses = [orbit_w2c_blender(az, el, dist) for az, el, dist in cases]
    result = _run_worker(
        tmp_path, {"track_to": [{"location": p.camera_position_world.tolist()} for p in poses]}
    )
    for (az, _el, _d), item, pose in zip(cases, result["track_to"], poses):
        w2c = _w2c_from_matrix_world(item["matrix_world"])
        a = math.radians(az)
        blender_right = w2c[0, :3]
        assert np.allclose(blender_right, [-math.sin(a), math.cos(a), 0.0], atol=1e-5)
        assert np.abs(w2c - pose.matrix).max() < 1e-5


# --------------------------------------------------------------------------------------------------------
# 3. Camera-frame rotation (rotate_to_camera) against a panoramic camera with the pose's rotation

CAMERA_ORBITS = (
    (0.0, 0.0),
    (37.0, 25.0),
    (160.0, -40.0),
    (285.0, 70.0),
    (330.0, -75.0),
    (225.0, 10.0),
)


def test_blender_panorama_layout_is_our_layout_rolled_by_a_quarter() -> None:
    """The roll derived in the module docstring, checked on direction grids alone (no Blender needed)."""
    blender = _blender_pano_camera_dirs(H, W)
    ours = direction_grid(H, W, "neural-gaffer-camera")
    assert np.abs(_to_ours(blender) - ours).max() < 1e-12
    # Fingerprint of Blender's panorama in the camera frame: centre = view direction -z, top = +y.
    assert np.allclose(
        blender[H // 2 - 1 : H // 2 + 1, W // 2 - 1 : W // 2 + 1].mean(axis=(0, 1)),
        [0, 0, -1],
        atol=2e-3,
    )
    assert blender[0, :, 1].min() > 0.99
    assert np.abs(blender - ours).max() > 1.0  # not the same layout without the roll


@needs_blender
def test_rotate_to_camera_matches_blender_panorama_in_camera_frame(tmp_path: Path) -> None:
    env = _synthetic_world(H, W, sharp=False)
    _write_exr(tmp_path / "env.exr", env)
    poses = [orbit_w2c_blender(az, el, 2.0) for az, el in CAMERA_ORBITS]
    renders = [
        {
            "env": str(tmp_path / "env.exr"),
            "out": str(tmp_path / f"cam{i}.exr"),
            "width": W,
            "height": H,
            # matrix_world rotation = camera axes in the world = (world -> camera)^T; location = origin.
            "rotation": pose.rotation.T.tolist(),
            "interpolation": "Linear",
        }
        for i, pose in enumerate(poses)
    ]
    result = _run_worker(tmp_path, {"renders": renders})
    print(f"camera frame: worker {result['wall_seconds']:.1f} s for {len(poses)} renders")

    ours_all = rotate_to_camera(
        EnvironmentMap(radiance_linear=env), poses, filter="bilinear"
    ).numpy()[0]
    cam_dirs_ours = direction_grid(H, W, "neural-gaffer-camera")
    cam_dirs_blender = _blender_pano_camera_dirs(H, W)
    for i, ((az, el), pose) in enumerate(zip(CAMERA_ORBITS, poses)):
        pano = _read_exr(tmp_path / f"cam{i}.exr")
        rolled = _to_ours(pano)
        ours = ours_all[i]
        dirs_world = cam_dirs_ours @ pose.rotation  # d_world = R^T d_cam, as rows
        _, src_row = _source_pixel(dirs_world, H, W)
        polar = (src_row < 0) | (src_row > H - 1)  # beyond the outermost row centres of the source
        away = ~polar
        err_all, err_away = _rel_rms(rolled, ours), _rel_rms(rolled[away], ours[away])
        max_away = float(np.abs(rolled - ours)[away].max())
        max_polar = float(np.abs(rolled - ours)[polar].max()) if polar.any() else 0.0
        model = _bilinear_cycles_model(env, dirs_world)
        err_model = float(np.abs(rolled - model).max())
        print(
            f"  pose (az {az}, el {el}): rel RMS {err_all:.3g} (all), {err_away:.3g} (away from the source "
            f"poles, max abs {max_away:.2g}); {int(polar.sum())} polar px, max abs {max_polar:.3g}; "
            f"vs Cycles v-periodic model max abs {err_model:.2g}"
        )
        assert err_away < 5e-4
        assert max_away < 5e-3
        # Pixels whose source point lies beyond the first/last row centre (at most half a row from a pole)
        # differ by up to ~0.4 x (top row - bottom row): Cycles blends them with the OPPOSITE pole's row.
        # The v-periodic model reproduces Blender everywhere, so that is the whole difference (a Cycles
        # artefact; rotate_to_camera's cross-pole neighbour is the physically right one).
        assert err_model < 5e-3

        for channel, maz, mel in MARKS:
            want = pose.rotation @ _direction(maz, mel)  # camera-frame direction of the mark
            in_blender = _angle_deg(
                _mark_direction(pano, cam_dirs_blender, channel, sharp=False), want
            )
            in_rolled = _angle_deg(
                _mark_direction(rolled, cam_dirs_ours, channel, sharp=False), want
            )
            in_ours = _angle_deg(_mark_direction(ours, cam_dirs_ours, channel, sharp=False), want)
            print(
                f"    mark {channel}: blender {in_blender:.2f}, rolled {in_rolled:.2f}, ours {in_ours:.2f} deg"
            )
            assert max(in_blender, in_rolled, in_ours) < 0.5 * PIXEL_DEG

        # Negative controls: no roll, the roll the other way, a mirrored layout, and the inverse rotation
        # (camera -> world used as world -> camera) all disagree. The last one only means something where
        # R is far from symmetric (orbit poses looking nearly straight up or at azimuth 90/270 are close
        # to half-turns, R ~ R^T).
        assert _rel_rms(pano, ours) > 0.1
        assert _rel_rms(np.roll(pano, W // 4, axis=1), ours) > 0.1
        assert _rel_rms(rolled[:, ::-1], ours) > 0.1
        if np.abs(pose.rotation - pose.rotation.T).max() > 0.5:
            inverse = rotate_to_camera(env, pose.rotation.T, filter="bilinear").numpy()[0, 0]
            assert _rel_rms(rolled, inverse) > 0.1
