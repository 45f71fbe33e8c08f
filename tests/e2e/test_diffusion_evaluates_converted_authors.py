"""Evaluation on the authors' released layout after `gaffer-data convert-authors`: the pairs carry
their pre-encoded maps, used as they are. A cross-package test (gaffer-data's converter feeds
gaffer-diffusion's evaluation): moved here unchanged, with its `_authors_release` helper, from
gaffer-diffusion's tests/test_evaluation.py."""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

pytest.importorskip("gaffer_data")
pytest.importorskip("gaffer_envmap.encode")

from gaffer_diffusion.evaluation import (
    EvaluationConfig,
    dataset_pairs,
    evaluate_dataset,
    pair_lighting,
)
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
from gaffer_diffusion.testing import tiny_model

RES = 32  # renders at half the tiny model's 64 px: evaluation resizes them


def _authors_release(root: Path) -> Path:
    """A two-view, three-lighting authors' split with its LDR/HDR maps (their layout, tiny)."""
    from gaffer_envmap.poses import orbit_w2c_blender

    split = root / "val_unseen" / "obj"
    rng = np.random.default_rng(1)
    for v in range(2):
        split.mkdir(parents=True, exist_ok=True)
        np.save(split / f"{v:03d}_RT.npy", orbit_w2c_blender(60.0 * v, 10.0, 2.0).matrix)
        for li, env in enumerate(("sky_000", "sky_045", "cave_090")):
            name = f"{v:03d}_{li:03d}_{env}.png"
            rgba = np.zeros((RES, RES, 4), np.uint8)
            rgba[..., :3] = 50 * li + 20
            rgba[8:24, 8:24, 3] = 255
            Image.fromarray(rgba).save(split / name)
            for folder in ("LDR", "HDR_rescaled"):
                (split / folder).mkdir(exist_ok=True)
                maps = rng.integers(0, 255, (RES, RES, 3), dtype=np.uint8)
                Image.fromarray(maps).save(split / folder / name)
    return root / "val_unseen"


def test_converted_authors_layout_uses_their_encoded_maps(tmp_path) -> None:
    from gaffer_data.convert import convert_authors
    from gaffer_diffusion.evaluation import EncodedLightingFiles, dataset_kind

    out = tmp_path / "converted"
    convert_authors(_authors_release(tmp_path), out)
    assert dataset_kind(out) == "authors"
    pairs = dataset_pairs(out)
    assert [p.name for p in pairs] == [
        "obj/000_000_to_001",
        "obj/000_000_to_002",
        "obj/001_000_to_001",
        "obj/001_000_to_002",
    ]
    lt = pairs[0].lighting
    assert isinstance(lt, EncodedLightingFiles) and lt.ldr.parent.name == "envmap_ldr"
    maps = pair_lighting(pairs[:1], RES, "neural-gaffer")
    ref = np.asarray(Image.open(lt.hdr).convert("RGB"), np.float32) / 255
    torch.testing.assert_close(maps.hdr[0], torch.from_numpy(ref).permute(2, 0, 1))
    result = evaluate_dataset(
        RelightPipeline(tiny_model()),
        pairs[:2],
        EvaluationConfig(sampling=SamplingConfig(num_inference_steps=1)),
        perceptual=None,
    )
    assert result.settings["lighting"] == "authors' pre-encoded maps"
    assert len(result.report.items) == 2
    assert len(dataset_pairs(out, input_lighting=1, limit=1)) == 1
