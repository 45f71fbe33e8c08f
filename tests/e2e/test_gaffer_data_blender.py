"""`read_gaffer_data_object` on a real `gaffer-data render-multiview` output (Cycles, 32 px, 4 samples).

This is the manifest path: with gaffer-data installed and `manifest.json` present, the env-map sources
come from gaffer-data's own reader, so `load_lighting_envmap` needs no `envmap_dir`.
"""

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

# The renderer runs in subprocesses; this process must never import bpy (as gaffer-data's tests).
if importlib.util.find_spec("bpy") is None:
    pytest.skip("bpy is not installed (gaffer-data[render])", allow_module_level=True)
gaffer_data_dataset = pytest.importorskip("gaffer_data.dataset")
gaffer_data_testing = pytest.importorskip("gaffer_data.testing")

from gaffer_nerf.data import load_lighting_envmap, read_gaffer_data_object  # noqa: E402

pytestmark = pytest.mark.blender

COLORS = {"red": (1.0, 0.02, 0.02), "blue": (0.02, 0.02, 1.0)}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("gd")
    gaffer_data_testing.write_cube_obj(root / "objects" / "cube.obj")
    gaffer_data_testing.write_uniform_envmaps(root / "envmaps", COLORS)
    cmd = [
        sys.executable, "-m", "gaffer_data.cli", "render-multiview", "--objects",
        str(root / "objects"), "--envmaps", str(root / "envmaps"), "--out", str(root / "out"),
        "--train-views", "4", "--test-views", "2", "--lightings", "2", "--resolution", "32",
        "--samples", "4", "--no-denoise", "--world-map-resolution", "64", "--no-flip",
        "--yaw-steps", "1", "--workers", "1", "--no-progress",
    ]  # fmt: skip
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr[-2000:]
    ds = gaffer_data_dataset.open_dataset(root / "out")
    return ds.object(ds.object_ids[0]).root


def test_reads_a_rendered_multiview_object_through_its_manifest(rendered: Path) -> None:
    obj = gaffer_data_dataset.read_object(rendered, verify=True)
    names = [li.envmap.name for li in obj.views[0].lit]
    assert sorted(names) == ["blue", "red"]
    red = names.index("red")
    blue = 1 - red
    scene = read_gaffer_data_object(rendered, lighting_index=red, verify=True)
    assert scene.train.num_views == 4 and scene.test is not None and scene.test.num_views == 2
    assert tuple(scene.train.rgb_srgb.shape) == (4, 32, 32, 3) and scene.train.alpha is not None
    # cameras: the transforms files, read by gaffer-nerf, agree with gaffer-data's cameras.npz
    poses = obj.poses()
    idx = [v.index for v in obj.split_views("train")]
    np.testing.assert_allclose(
        scene.train.cameras.c2w_opencv.double().numpy(), poses.c2w_opencv[idx], atol=1e-5
    )
    np.testing.assert_allclose(
        scene.train.cameras.w2c_blender().double().numpy(), poses.w2c_blender[idx], atol=1e-5
    )
    torch.testing.assert_close(
        scene.train.cameras.focal_px[0].double(),
        torch.tensor([obj.intrinsics.fx, obj.intrinsics.fy], dtype=torch.float64),
    )
    # the manifest supplied every lighting's source, so no env-map folder is needed
    assert len(scene.lightings) == 2
    for li in scene.lightings:
        assert li.source is not None and Path(li.source).is_file()
        env = load_lighting_envmap(li)
        rgb = env.radiance_linear.reshape(-1, 3).mean(axis=0)
        expected = COLORS[names[li.lighting_index]]
        np.testing.assert_allclose(rgb, expected, rtol=1e-3, atol=1e-4)
    # the images follow the lighting: the cube is red under the red map and blue under the blue one
    in_red = scene.train.rgb_srgb[scene.train.alpha > 0.99]  # [K, 3] object pixels
    under_blue = read_gaffer_data_object(rendered, lighting_index=blue).train
    in_blue = under_blue.rgb_srgb[under_blue.alpha > 0.99]
    assert len(in_red) > 50 and float(in_red[:, 0].mean()) > float(in_red[:, 2].mean()) + 0.2
    assert float(in_blue[:, 2].mean()) > float(in_blue[:, 0].mean()) + 0.2
    torch.testing.assert_close(under_blue.alpha, scene.train.alpha)  # same views, same mask
