"""gaffer-data's own multi-view writer output (`nerf_transforms`) reads back in gaffer-nerf (a
cross-package test, moved here unchanged from gaffer-nerf's tests/test_data.py)."""

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gaffer_nerf.data import read_gaffer_data_object


def test_gaffer_data_writer_format_round_trip(tmp_path: Path) -> None:
    """gaffer-data's own `nerf_transforms` output, with synthetic images at its paths, reads back."""
    plan_mod = pytest.importorskip("gaffer_data.render.plan")
    from gaffer_data.config import MultiviewConfig, multiview_render_config

    cfg = multiview_render_config(MultiviewConfig(train_views=3, test_views=1), resolution=32)
    pool = [
        plan_mod.PoolEntry(name=f"m{i}", path=Path(f"/x/m{i}.exr"), sha256="0" * 64)
        for i in range(2)
    ]
    plan = plan_mod.plan_for("o", "/x/o.glb", pool, cfg)
    poses = plan_mod.plan_poses(plan)
    for split in ("train", "test"):
        body = plan_mod.nerf_transforms(plan, split)
        (tmp_path / f"transforms_{split}.json").write_text(json.dumps(body))
        for fr in body["frames"]:
            for lit in fr["lit"]:
                p = tmp_path / (lit["file_path"] + ".png")
                p.parent.mkdir(parents=True, exist_ok=True)
                Image.fromarray(np.full((32, 32, 4), 128, np.uint8), "RGBA").save(p)
    scene = read_gaffer_data_object(tmp_path, lighting_index=2)
    assert scene.train.num_views == 3 and len(scene.lightings) == cfg.lightings
    views = [v.index for v in plan.views if v.split == "train"]
    np.testing.assert_allclose(
        scene.train.cameras.c2w_opencv.numpy(), poses.c2w_opencv[views], atol=1e-5
    )
    np.testing.assert_allclose(
        scene.train.cameras.w2c_blender().numpy(), poses.w2c_blender[views], atol=1e-5
    )
