"""Multi-view 3D render sets: layout, splits, shared lightings, NeRF-Synthetic transforms."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gaffer_data.config import MultiviewConfig, RenderConfig, multiview_render_config
from gaffer_data.errors import ConfigError
from gaffer_data.render.plan import (
    PoolEntry,
    camera_angle_x,
    nerf_transforms,
    plan_for,
    plan_multiview_object,
    plan_poses,
)
from gaffer_data.testing import write_cube_obj, write_uniform_envmaps


def _pool(n: int = 6) -> list[PoolEntry]:
    return [PoolEntry(name=f"m{i}", path=Path(f"/x/m{i}.exr"), sha256="0" * 64) for i in range(n)]


def _config(**mv: object) -> RenderConfig:
    multiview = MultiviewConfig(**{"train_views": 100, "test_views": 20, **mv})  # type: ignore[arg-type]
    return multiview_render_config(multiview, resolution=256)


def test_paper_setup_splits_and_shared_lightings() -> None:
    cfg = _config()
    assert cfg.views == 120 and cfg.lightings == 4 and not cfg.area_light_render
    plan = plan_for("obj", "/x/obj.glb", _pool(), cfg)
    assert [v.split for v in plan.views] == ["train"] * 100 + ["test"] * 20
    assert [v.index for v in plan.views] == list(range(120))
    first = [li.envmap for li in plan.views[0].lit]
    assert len({e.name for e in first}) == 4  # distinct maps while the pool allows
    assert all([li.envmap for li in v.lit] == first for v in plan.views)
    assert all(v.alpha is not None for v in plan.views)  # transparent film: masks for the NeRF
    assert plan == plan_multiview_object("obj", "/x/obj.glb", _pool(), cfg)  # deterministic
    other = plan_for("obj2", "/x/obj.glb", _pool(), cfg)
    assert other.views[0].camera != plan.views[0].camera


def test_sphere_layout_is_uniform_in_solid_angle_and_splits_cover_it() -> None:
    plan = plan_for("obj", "/x/obj.glb", _pool(), _config(elevation_deg=(-30.0, 90.0)))
    elev = np.array([v.camera.elevation_deg for v in plan.views])
    assert elev.min() > -30.0 and elev.max() < 90.0
    pos = np.array([v.camera.position for v in plan.views])
    np.testing.assert_allclose(np.linalg.norm(pos, axis=1), 2.0)
    # Uniform in solid angle: z / r is uniform on [sin(-30 deg), 1].
    z = np.sort(pos[:, 2] / 2.0)
    expected = -0.5 + 1.5 * (np.arange(120) + 0.5) / 120
    np.testing.assert_allclose(z, expected, atol=1e-9)
    # Held-out views are spread over the band, not clustered at one end.
    test_z = pos[100:, 2] / 2.0
    assert test_z.min() < 0.0 and test_z.max() > 0.5
    # No two cameras coincide.
    d = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(120) * 9
    assert d.min() > 0.1


def test_orbit_layout() -> None:
    plan = plan_for("o", "/x/o.glb", _pool(), _config(layout="orbit", train_views=8, test_views=4))
    elev = {round(v.camera.elevation_deg, 9) for v in plan.views}
    az = np.sort([v.camera.azimuth_deg for v in plan.views])
    assert elev == {30.0}
    np.testing.assert_allclose(np.diff(az), 30.0, atol=1e-9)


def test_transforms_are_nerf_synthetic_blender_c2w() -> None:
    cfg = _config(train_views=6, test_views=3)
    plan = plan_for("o", "/x/o.glb", _pool(2), cfg)
    poses = plan_poses(plan)
    train, test = nerf_transforms(plan, "train"), nerf_transforms(plan, "test")
    assert len(train["frames"]) == 6 and len(test["frames"]) == 3  # type: ignore[arg-type]
    assert train["camera_angle_x"] == pytest.approx(2 * np.arctan(16 / 35))
    assert camera_angle_x(cfg) == pytest.approx(np.deg2rad(49.134), abs=1e-4)
    assert train["fl_x"] == pytest.approx(35 / 32 * 256) and train["w"] == 256
    for frame in test["frames"]:  # type: ignore[union-attr]
        v = frame["view_index"]
        c2w = np.array(frame["transform_matrix"])
        np.testing.assert_allclose(c2w[3], [0, 0, 0, 1])
        # Blender/OpenGL camera: -z looks at the origin, +y is up (positive world z component).
        np.testing.assert_allclose(-c2w[:3, 2], -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3]), atol=1e-9)
        assert c2w[2, 1] >= 0
        # The same camera as cameras.npz: OpenCV c2w = Blender c2w with y and z flipped.
        np.testing.assert_allclose(c2w @ np.diag([1, -1, -1, 1]), poses.c2w_opencv[v], atol=1e-9)
        assert frame["file_path"] == f"./lit/{v:03d}_000"
        assert [f["file_path"] for f in frame["lit"]] == [
            f"./lit/{v:03d}_{i:03d}" for i in range(4)
        ]
    # 4 lightings from a pool of 2: drawn with replacement, listed once at the top level.
    assert [x["lighting_index"] for x in train["lightings"]] == [0, 1, 2, 3]  # type: ignore[union-attr]
    assert {x["envmap"] for x in train["lightings"]} <= {"m0", "m1"}  # type: ignore[union-attr]
    with pytest.raises(ConfigError, match="split"):
        nerf_transforms(plan, "val")
    with pytest.raises(ConfigError, match="multi-view"):
        nerf_transforms(plan_for("o", "/x/o.glb", _pool(2), RenderConfig()), "train")


def test_multiview_config_validation_and_round_trip() -> None:
    cfg = _config(train_views=4, test_views=2)
    assert RenderConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    assert RenderConfig.from_dict(RenderConfig().to_dict()).multiview is None
    with pytest.raises(ConfigError, match="multiview_render_config"):
        RenderConfig(views=3, multiview=MultiviewConfig(train_views=4, test_views=2))
    for bad in (
        {"train_views": 0},
        {"layout": "spiral"},
        {"distance": 0.0},
        {"elevation_deg": (0, 95)},
    ):
        with pytest.raises(ConfigError, match="multiview"):
            MultiviewConfig(**bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="multiview"):
        plan_multiview_object("o", "/x", _pool(), RenderConfig())


@pytest.mark.blender
def test_render_multiview_cli(tmp_path: Path) -> None:
    if importlib.util.find_spec("bpy") is None:  # never import it here: pymeshlab may be loaded
        pytest.skip("bpy is not installed (gaffer-data[render])")
    from PIL import Image

    from gaffer_data.dataset import open_dataset

    write_cube_obj(tmp_path / "objects" / "cube.obj")
    write_uniform_envmaps(tmp_path / "envmaps", {"red": (1, 0.02, 0.02), "blue": (0.02, 0.02, 1)})
    cmd = [
        sys.executable, "-m", "gaffer_data.cli", "render-multiview", "--objects",
        str(tmp_path / "objects"), "--envmaps", str(tmp_path / "envmaps"), "--out",
        str(tmp_path / "out"), "--train-views", "4", "--test-views", "2", "--lightings", "2",
        "--resolution", "32", "--samples", "4", "--no-denoise", "--world-map-resolution", "64",
        "--yaw-steps", "4", "--no-progress",
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "12 images" in result.stdout
    ds = open_dataset(tmp_path / "out")
    assert ds.config is not None and ds.config.multiview is not None
    obj = next(ds.iter_objects(verify=True))
    assert len(obj.split_views("train")) == 4 and len(obj.split_views("test")) == 2
    assert {f.path for f in obj.files if f.kind == "transforms"} == {
        "transforms_train.json",
        "transforms_test.json",
    }
    names = {li.envmap.name for li in obj.views[0].lit}
    assert names == {"red", "blue"}
    test = json.loads(obj.transforms_path("test").read_text())
    for frame in test["frames"]:
        for lit in frame["lit"]:
            with Image.open(obj.root / (lit["file_path"] + ".png")) as im:
                rgba = np.array(im)
            assert rgba.shape == (32, 32, 4)
            assert (
                rgba[16, 16, 3] == 255 and rgba[0, 0, 3] == 0
            )  # object in front, film transparent
            red = lit["lighting_index"] == [li.envmap.name for li in obj.views[0].lit].index("red")
            r, b = int(rgba[16, 16, 0]), int(rgba[16, 16, 2])
            assert (r > b) == red
