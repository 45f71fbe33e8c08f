"""Multi-view readers: NeRF-Synthetic and gaffer-data transforms, lightings, env maps, errors."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_nerf.data import load_lighting_envmap, read_gaffer_data_object, read_transforms_folder
from gaffer_nerf.data.transforms import LightingInfo
from gaffer_nerf.errors import CameraError, DatasetError, DatasetNotFoundError
from gaffer_nerf.testing import orbit_cameras, sphere_viewset, write_sphere_scene


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory):
    return write_sphere_scene(
        tmp_path_factory.mktemp("sphere"), train_views=4, test_views=2, resolution=32
    )


def test_reads_gaffer_data_layout_per_lighting(written) -> None:
    s0 = read_gaffer_data_object(written.root, lighting_index=0)
    s1 = read_gaffer_data_object(written.root, lighting_index=1)
    assert s0.train.num_views == 4 and s0.test is not None and s0.test.num_views == 2
    assert [li.envmap for li in s0.lightings] == ["env0", "env1"]
    torch.testing.assert_close(s0.train.cameras.c2w_opencv, s1.train.cameras.c2w_opencv)
    assert not torch.equal(s0.train.rgb_srgb, s1.train.rgb_srgb)
    # the PNG round trip equals the in-memory render (8-bit quantised, over white)
    ref = sphere_viewset(orbit_cameras(4, resolution=32), written.envmaps[0])
    torch.testing.assert_close(s0.train.rgb_srgb, ref.rgb_srgb, atol=1.5 / 255, rtol=0)
    torch.testing.assert_close(
        s0.train.cameras.c2w_opencv, ref.cameras.c2w_opencv, atol=1e-5, rtol=0
    )
    assert s0.train.alpha is not None and float(s0.train.alpha.max()) == 1.0
    env = load_lighting_envmap(s0.lighting(1), written.envmap_dir)
    np.testing.assert_allclose(env.radiance_linear, written.envmaps[1].radiance_linear, rtol=1e-3)
    with pytest.raises(DatasetError, match="lighting_index"):
        s0.lighting(7)


def test_plain_nerf_synthetic_folder(tmp_path: Path, written) -> None:
    # camera_angle_x only, RGB pngs with suffix, no lit lists
    meta = json.loads((written.root / "transforms_train.json").read_text())
    frames = []
    for k, fr in enumerate(meta["frames"]):
        rgb = np.asarray(Image.open(written.root / (fr["file_path"] + ".png")).convert("RGB"))
        Image.fromarray(rgb).save(tmp_path / f"r_{k}.png")
        frames.append({"file_path": f"./r_{k}.png", "transform_matrix": fr["transform_matrix"]})
    (tmp_path / "transforms_train.json").write_text(
        json.dumps({"camera_angle_x": meta["camera_angle_x"], "frames": frames})
    )
    scene = read_transforms_folder(tmp_path)
    assert scene.test is None and scene.lightings == () and scene.train.alpha is None
    gd = read_gaffer_data_object(written.root)
    torch.testing.assert_close(
        scene.train.cameras.focal_px, gd.train.cameras.focal_px, atol=1e-3, rtol=0
    )
    half = read_transforms_folder(tmp_path, downscale=2)
    assert half.train.rgb_srgb.shape[1:3] == (16, 16)
    torch.testing.assert_close(half.train.cameras.focal_px, scene.train.cameras.focal_px / 2)
    with pytest.raises(DatasetError, match="lighting_index"):
        read_transforms_folder(tmp_path, lighting_index=1)


def test_reader_errors(tmp_path: Path, written) -> None:
    with pytest.raises(DatasetNotFoundError, match=r"transforms_train\.json"):
        read_transforms_folder(tmp_path)
    meta = json.loads((written.root / "transforms_train.json").read_text())
    bad = dict(meta, frames=[dict(meta["frames"][0], file_path="./lit/missing")])
    (tmp_path / "transforms_train.json").write_text(json.dumps(bad))
    with pytest.raises(DatasetNotFoundError, match=r"missing\.png"):
        read_transforms_folder(tmp_path)
    nan = [dict(f, file_path=str(written.root / f["file_path"])) for f in meta["frames"]]
    nan[1] = dict(nan[1], transform_matrix=[[float("nan")] * 4] * 3 + [[0, 0, 0, 1]])
    (tmp_path / "transforms_train.json").write_text(json.dumps(dict(meta, frames=nan)))
    with pytest.raises(CameraError, match="NaN"):
        read_transforms_folder(tmp_path)
    (tmp_path / "transforms_train.json").write_text(json.dumps({"frames": []}))
    with pytest.raises(DatasetError, match="frames"):
        read_transforms_folder(tmp_path)
    with pytest.raises(DatasetNotFoundError, match="--envmaps"):
        load_lighting_envmap(LightingInfo(lighting_index=0, envmap="nope"), tmp_path)


def test_envmap_augmentation_is_applied(written) -> None:
    info = LightingInfo(lighting_index=1, envmap="env1", flip=True, yaw_step=1, num_steps=4)
    env = load_lighting_envmap(info, written.envmap_dir)
    ref = written.envmaps[1].radiance_linear[:, ::-1]
    ref = np.roll(ref, -(ref.shape[1] // 4), axis=1)
    np.testing.assert_allclose(env.radiance_linear, ref, rtol=1e-3)


def test_viewset_select_keeps_images_cameras_and_names_together(written) -> None:
    """`ViewSet.select` picks views in the order given, every per-view field alike."""
    views = read_gaffer_data_object(written.root, lighting_index=0).train
    order = [3, 0, 2]
    sub = views.select(order)
    assert sub.num_views == 3 and sub.names == tuple(views.names[k] for k in order)
    assert torch.equal(sub.rgb_srgb, views.rgb_srgb[order])
    assert views.alpha is not None and sub.alpha is not None
    assert torch.equal(sub.alpha, views.alpha[order])
    assert torch.equal(sub.cameras.c2w_opencv, views.cameras.c2w_opencv[order])
    assert torch.equal(sub.cameras.rays([0]).dirs_world, views.cameras.rays([3]).dirs_world)
    assert sub.lighting_index == views.lighting_index
