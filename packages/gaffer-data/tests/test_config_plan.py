"""Config validation, deterministic planning, poses and augmentation (pure, no bpy)."""

from pathlib import Path

import numpy as np
import pytest

import gaffer_data
from gaffer_data.config import (
    AugmentConfig,
    CameraConfig,
    MultiviewConfig,
    RenderConfig,
    multiview_render_config,
)
from gaffer_data.dataset.schema import EnvmapRef
from gaffer_data.errors import ConfigError, InputError
from gaffer_data.render.plan import (
    PoolEntry,
    look_at_c2w_blender,
    plan_for,
    plan_object,
    plan_poses,
    scan_envmaps,
)
from gaffer_data.render.runner import Shard
from gaffer_data.render.worker import augment_envmap_pixels
from gaffer_data.testing import tiny_config, write_uniform_envmaps
from gaffer_envmap.augment import AugmentSpec
from gaffer_envmap.environment_map import EnvironmentMap


def _pool(n: int = 3) -> list[PoolEntry]:
    return [PoolEntry(name=f"m{i}", path=Path(f"/x/m{i}.exr"), sha256="0" * 64) for i in range(n)]


def test_version_is_semver() -> None:
    parts = gaffer_data.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)


def test_defaults_follow_the_paper() -> None:
    cfg = RenderConfig()
    assert (cfg.views, cfg.lightings, cfg.resolution, cfg.samples, cfg.denoise) == (
        12,
        16,
        512,
        128,
        True,
    )
    assert cfg.camera == CameraConfig(
        lens_mm=35.0,
        sensor_mm=32.0,
        elevation_deg=(-60.0, 90.0),
        azimuth_deg=(0.0, 360.0),
        distance=(1.5, 2.2),
    )
    assert (
        cfg.bounces.diffuse,
        cfg.bounces.glossy,
        cfg.bounces.transparent,
        cfg.bounces.transmission,
    ) == (1, 1, 3, 3)
    assert (
        cfg.view_transform == "Filmic"
        and cfg.envmap_strength == 1.0
        and cfg.area_light.world_grey == 0.35
    )


def test_config_round_trip_ignores_unknown_keys() -> None:
    cfg = tiny_config(seed=7)
    data = cfg.to_dict() | {"from_the_future": 1}
    assert RenderConfig.from_dict(data) == cfg


@pytest.mark.parametrize(
    "kwargs",
    [
        {"views": 0},
        {"resolution": -1},
        {"lightings": 0, "area_light_render": False},
        {"view_transform": "Fancy"},
        {"camera": {"elevation_deg": (10.0, -10.0)}},
        {"camera": {"distance": (0.0, 1.0)}},
        {"augment": {"yaw_steps": 0}},
    ],
)
def test_config_rejects_bad_values(kwargs: dict) -> None:
    with pytest.raises(ConfigError, match="`"):
        RenderConfig.from_dict(RenderConfig().to_dict() | kwargs)


def test_plan_is_deterministic_and_in_range() -> None:
    cfg = RenderConfig(views=50, lightings=4)
    a = plan_object("obj", "/x/obj.glb", _pool(), cfg)
    b = plan_object("obj", "/x/obj.glb", _pool(), cfg)
    assert a == b
    for view in a.views:
        cam = view.camera
        assert (
            -60 <= cam.elevation_deg <= 90
            and 0 <= cam.azimuth_deg <= 360
            and 1.5 <= cam.distance <= 2.2
        )
        assert np.isclose(np.linalg.norm(cam.position), cam.distance)
        assert view.area is not None and -1 <= view.area.light.location[0] <= 1
        assert 300 <= view.area.light.energy <= 500 and 0.5 <= view.area.light.location[2] <= 1.5
        assert all(0 <= li.envmap.yaw_step < 8 for li in view.lit)
    other = plan_object("obj", "/x/obj.glb", _pool(), RenderConfig(views=50, lightings=4, seed=1))
    assert other.views[0].camera != a.views[0].camera
    assert plan_object("obj2", "/x/obj.glb", _pool(), cfg).views[0].camera != a.views[0].camera


def test_plan_draws_cover_the_pool_and_augmentations() -> None:
    plan = plan_object("o", "/x/o.glb", _pool(3), RenderConfig(views=12, lightings=16))
    refs = [li.envmap for v in plan.views for li in v.lit]
    assert {r.name for r in refs} == {"m0", "m1", "m2"}
    assert {r.flip for r in refs} == {True, False}
    assert {r.yaw_step for r in refs} == set(range(8))


def test_cameras_do_not_depend_on_the_number_of_lightings() -> None:
    a = plan_object("o", "/x/o.glb", _pool(), RenderConfig(lightings=1))
    b = plan_object("o", "/x/o.glb", _pool(), RenderConfig(lightings=16))
    assert [v.camera for v in a.views] == [v.camera for v in b.views]


def test_empty_pool_needs_zero_lightings() -> None:
    with pytest.raises(InputError, match="pool"):
        plan_object("o", "/x/o.glb", [], RenderConfig())
    plan = plan_object("o", "/x/o.glb", [], RenderConfig(lightings=0))
    assert all(v.lit == () and v.area is not None for v in plan.views)


def test_poses_look_at_origin_and_match_gaffer_envmap() -> None:
    poses_mod = pytest.importorskip("gaffer_envmap.poses")
    plan = plan_object("o", "/x/o.glb", _pool(), RenderConfig(views=20))
    poses = plan_poses(plan)
    assert poses.w2c_blender.shape == (20, 3, 4) and poses.c2w_opencv.shape == (20, 4, 4)
    for v, view in enumerate(plan.views):
        ref = poses_mod.look_at_w2c_blender(np.array(view.camera.position))
        np.testing.assert_allclose(poses.w2c_blender[v], ref.matrix, atol=1e-9)
        np.testing.assert_allclose(poses.c2w_opencv[v], ref.to_c2w_opencv().matrix, atol=1e-9)
        # OpenCV camera +z looks at the origin.
        c2w = poses.c2w_opencv[v]
        to_origin = -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])
        np.testing.assert_allclose(c2w[:3, 2], to_origin, atol=1e-9)
    assert np.isclose(poses.intrinsics[0, 0], 35 / 32 * 512)


def test_look_at_straight_down_is_defined() -> None:
    c2w = look_at_c2w_blender((0.0, 0.0, 2.0))
    assert np.all(np.isfinite(c2w))
    np.testing.assert_allclose(c2w[:3, :3] @ c2w[:3, :3].T, np.eye(3), atol=1e-12)


def _previous_look_at_c2w_blender(position, target=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The formula gaffer-data used before delegating to gaffer-envmap (kept to prove bit-identity)."""
    pos = np.asarray(position, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - pos
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -forward, pos
    return c2w


def test_look_at_delegates_to_gaffer_envmap_bit_identically() -> None:
    rng = np.random.default_rng(1234)
    positions = [tuple(p) for p in rng.normal(size=(500, 3)) * rng.uniform(0.1, 5.0, (500, 1))]
    positions += [(0.0, 0.0, 2.0), (0.0, 0.0, -1.7), (1e-12, 0.0, 3.0)]  # straight down / up
    targets = [(0.0, 0.0, 0.0)] * len(positions)
    targets[:100] = [tuple(t) for t in rng.normal(size=(100, 3))]
    for position, target in zip(positions, targets, strict=True):
        ours = look_at_c2w_blender(position, target)
        np.testing.assert_array_equal(ours, _previous_look_at_c2w_blender(position, target))
    # And the planned cameras of real plans (relighting and multi-view), through cameras.npz's payload.
    multiview = [
        multiview_render_config(MultiviewConfig(train_views=8, test_views=4, **kw), resolution=32)
        for kw in ({}, {"layout": "orbit", "orbit_elevation_deg": 90.0})
    ]
    for config in (RenderConfig(views=50), tiny_config(views=7), *multiview):
        plan = plan_for("obj", "/x/o.glb", _pool(), config)
        old = np.stack([_previous_look_at_c2w_blender(v.camera.position) for v in plan.views])
        new = np.stack([look_at_c2w_blender(v.camera.position) for v in plan.views])
        np.testing.assert_array_equal(new, old)
        poses = plan_poses(plan)
        np.testing.assert_array_equal(poses.w2c_blender, np.linalg.inv(old)[:, :3, :])


@pytest.mark.parametrize("flip", [False, True])
@pytest.mark.parametrize("yaw_step", [0, 1, 3])
def test_worker_augmentation_is_gaffer_envmaps(flip: bool, yaw_step: int) -> None:
    rgba = np.random.default_rng(0).random((8, 16, 4)).astype(np.float32)
    ref = EnvmapRef(
        name="m", source="/x/m.exr", source_sha256="0", flip=flip, yaw_step=yaw_step, num_steps=4
    )
    ours = augment_envmap_pixels(rgba, ref)
    env = EnvironmentMap(radiance_linear=rgba[..., :3])
    theirs = AugmentSpec(flip=flip, yaw_step=yaw_step, num_steps=4).apply(env).radiance_linear
    assert ours.shape == (8, 16, 4) and ours.dtype == np.float32
    np.testing.assert_array_equal(ours[..., :3], theirs)
    np.testing.assert_array_equal(ours[..., 3], 1.0)
    if yaw_step == 1 and not flip:  # a quarter turn counter-clockwise = roll left by We / 4
        np.testing.assert_array_equal(ours[..., :3], np.roll(rgba[..., :3], -4, axis=1))


def test_worker_augmentation_rejects_bad_maps() -> None:
    ref = EnvmapRef(
        name="m", source="/x/m.exr", source_sha256="0", flip=False, yaw_step=1, num_steps=3
    )
    with pytest.raises(InputError, match=r"augment\.yaw_steps"):
        augment_envmap_pixels(np.zeros((8, 16, 3), np.float32), ref)
    with pytest.raises(InputError, match="2:1"):
        augment_envmap_pixels(np.zeros((5, 16, 3), np.float32), ref)


def test_shards_partition_the_objects() -> None:
    ids = [f"object_{i}" for i in range(200)]
    shards = [Shard(index=i, count=3) for i in range(3)]
    owners = [[s.contains(oid) for s in shards].count(True) for oid in ids]
    assert owners == [1] * len(ids)
    assert Shard.parse("2/3") == shards[2]
    for bad in ("3/3", "x", "1/0"):
        with pytest.raises(ConfigError, match="shard"):
            Shard.parse(bad)


def test_scan_envmaps(tmp_path) -> None:
    write_uniform_envmaps(tmp_path, {"b": (0, 0, 1), "a": (1, 0, 0)})
    (tmp_path / "notes.txt").write_text("x")
    pool = scan_envmaps(tmp_path)
    assert [e.name for e in pool] == ["a", "b"] and all(len(e.sha256) == 64 for e in pool)
    with pytest.raises(InputError, match="envmaps"):
        scan_envmaps(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"no \.exr"):
        scan_envmaps(tmp_path / "empty")


def test_augment_config_validation() -> None:
    with pytest.raises(ConfigError):
        AugmentConfig(yaw_steps=0)


def test_an_object_locked_by_another_run_is_left_to_it(tmp_path, monkeypatch) -> None:
    fcntl = pytest.importorskip("fcntl")
    from gaffer_data.dataset.reader import MANIFEST_NAME, OBJECTS_DIR
    from gaffer_data.render import runner

    source = tmp_path / "o.glb"
    source.write_bytes(b"not rendered here")
    plan = plan_for("obj", str(source), _pool(), tiny_config())
    out, calls = tmp_path / "out", []

    def fake_render(plan, root, *args):  # the Blender attempts, which need the lock
        calls.append(root)
        return runner.ObjectResult(object_id=plan.object_id, failure=None, image_seconds=())

    monkeypatch.setattr(runner, "_render_locked", fake_render)
    options = runner.RunOptions(progress=False)
    lock = out / runner.LOCKS_DIR / "obj.lock"
    lock.parent.mkdir(parents=True)
    with open(lock, "a+b") as other_run:  # another process holds the object's lock
        fcntl.flock(other_run, fcntl.LOCK_EX | fcntl.LOCK_NB)
        busy = runner.render_object(plan, out, options, threads=1)
    assert busy.failure is not None and busy.failure.attempts == 0
    assert busy.failure.reason.startswith("busy") and "obj.lock" in busy.failure.reason
    assert calls == []  # nothing touched the other run's folder
    assert runner.render_object(plan, out, options, threads=1).failure is None  # lock released
    assert len(calls) == 1
    # finished by another run since this one planned it: not rendered again
    (out / OBJECTS_DIR / "obj").mkdir(parents=True)
    (out / OBJECTS_DIR / "obj" / MANIFEST_NAME).write_text("{}")
    assert runner.render_object(plan, out, options, threads=1).failure is None
    assert len(calls) == 1
