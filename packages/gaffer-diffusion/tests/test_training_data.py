"""Training data: samples, compositing, determinism, resumable sharded order, broken files."""

import logging
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("gaffer_data")

from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.training import (
    DataConfig,
    DataError,
    KeySampler,
    RelightTrainDataset,
    cfg_dropout_masks,
    collate_items,
    encode_batch_lighting,
    split_object_ids,
)
from gaffer_diffusion.training.dataset import load_image_on_white
from gaffer_diffusion.training.testing import write_synthetic_dataset


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("ds") / "data", objects=3, views=2, lightings=3
    )


def _cfg(root: Path, **kw: object) -> DataConfig:
    return DataConfig(root=root, envmap_height=8, **kw)  # type: ignore[arg-type]


def test_item_shapes_and_targets(root: Path) -> None:
    ds = RelightTrainDataset([root], _cfg(root), 16)
    assert len(ds) == 6
    item = ds[3]
    assert item.input_image.shape == (3, 16, 16) and item.target_images.shape == (2, 3, 16, 16)
    assert item.envmaps.shape == (2, 8, 16, 3) and item.w2c_blender.shape == (3, 4)
    assert item.input_alpha is not None and item.input_alpha.shape == (1, 16, 16)
    batch = collate_items([ds[0], ds[1], ds[2]])
    assert batch.target_images.shape == (3, 2, 3, 16, 16) and batch.envmaps.shape == (
        3,
        2,
        8,
        16,
        3,
    )
    assert batch.skipped == 0


def test_same_key_same_item_and_area_probability(root: Path) -> None:
    ds = RelightTrainDataset([root], _cfg(root), 16, seed=3)
    a, b = ds[7], ds[7]
    assert torch.equal(a.input_image, b.input_image) and torch.equal(a.envmaps, b.envmaps)
    always = RelightTrainDataset([root], _cfg(root, area_light_prob=1.0), 16)
    never = RelightTrainDataset([root], _cfg(root, area_light_prob=0.0), 16)
    assert all(always[k].input_is_area for k in range(12))
    assert not any(never[k].input_is_area for k in range(12))
    freq = np.mean(
        [RelightTrainDataset([root], _cfg(root), 16)[k].input_is_area for k in range(300)]
    )
    assert 0.05 < freq < 0.16  # paper: 10% area-light inputs


def test_composite_on_white(tmp_path: Path) -> None:
    from PIL import Image

    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[2:6, 2:6] = (255, 0, 0, 255)
    rgba[0, 0] = (0, 0, 0, 128)  # half-transparent black over white -> ~0.5 grey
    Image.fromarray(rgba, "RGBA").save(tmp_path / "a.png")
    img = load_image_on_white(tmp_path / "a.png", 8)
    assert torch.allclose(img[:, 7, 7], torch.ones(3))
    assert torch.allclose(img[:, 3, 3], torch.tensor([1.0, 0.0, 0.0]))
    assert abs(float(img[0, 0, 0]) - (1 - 128 / 255)) < 1e-6
    assert load_image_on_white(tmp_path / "a.png", 4).shape == (3, 4, 4)
    from gaffer_diffusion.training.dataset import load_rgba_on_white

    rgb, alpha = load_rgba_on_white(tmp_path / "a.png", 8)
    assert torch.equal(rgb, img) and alpha.shape == (1, 8, 8)
    assert float(alpha[0, 3, 3]) == 1.0 and float(alpha[0, 7, 7]) == 0.0
    assert abs(float(alpha[0, 0, 0]) - 128 / 255) < 1e-6


def test_sampler_resumes_and_shards_exactly() -> None:
    full = KeySampler(5, seed=1)
    stream = [k for _, k in zip(range(23), full)]
    assert sorted(k % 5 for k in stream[:5]) == list(range(5))  # an epoch is a permutation
    resumed = [k for _, k in zip(range(11), KeySampler(5, seed=1, start=12))]
    assert resumed == stream[12:]
    r0 = [k for _, k in zip(range(6), KeySampler(5, seed=1, start=4, rank=0, world_size=2))]
    r1 = [k for _, k in zip(range(6), KeySampler(5, seed=1, start=4, rank=1, world_size=2))]
    assert r0 == stream[4:16:2] and r1 == stream[5:17:2]


def test_split_is_deterministic_and_refuses_to_hold_out_every_object() -> None:
    ids = [f"o{i}" for i in range(10)]
    train, val = split_object_ids(ids, 3)
    assert len(val) == 3 and set(train) | set(val) == set(ids)
    assert split_object_ids(list(reversed(ids)), 3) == (train, val)
    assert split_object_ids(["a"], 0) == (("a",), ())
    assert len(split_object_ids(ids, 9)[0]) == 1  # the most that can be held out
    # `val_objects: 50` on 12 objects was cut to 11 silently, leaving 1 to train on
    for objects, num_val in ((ids, 10), (ids, 50), (["a"], 1)):
        with pytest.raises(ConfigError, match=r"`data\.val_objects`") as info:
            split_object_ids(objects, num_val)
        message = str(info.value)
        assert f"is {num_val}" in message and f"holds {len(objects)} object" in message


def test_missing_and_corrupt_files_are_skipped_with_a_count(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    root = write_synthetic_dataset(tmp_path / "d", objects=3, views=2, lightings=3)
    (root / "objects" / "obj0" / "lit" / "000_000.png").unlink()
    (root / "objects" / "obj1" / "lit" / "001_002.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    (root / "objects" / "obj2" / "manifest.json").write_text("{not json")
    with caplog.at_level(logging.WARNING):
        ds = RelightTrainDataset([root], _cfg(root), 16)
    assert (
        len(ds.objects) == 2 and len(ds.skipped_objects) == 1 and "unreadable object" in caplog.text
    )
    items = [ds[k] for k in range(40)]
    skipped = sum(i.skipped for i in items)
    assert skipped > 0 and any(
        "000_000.png" in f or "001_002" in f for i in items for f in i.skipped_files
    )
    assert collate_items(items[:8]).skipped == sum(i.skipped for i in items[:8])


def test_all_broken_raises_a_clear_error(tmp_path: Path) -> None:
    root = write_synthetic_dataset(tmp_path / "d", objects=1, views=1, lightings=3)
    for p in (root / "objects" / "obj0").rglob("*.png"):
        p.unlink()
    ds = RelightTrainDataset([root], _cfg(root, max_load_retries=3), 16)
    with pytest.raises(DataError, match="could not be read"):
        ds[0]
    with pytest.raises(DataError, match="No usable view"):
        RelightTrainDataset([root], _cfg(root, targets_per_sample=5), 16)


def test_moved_envmaps_are_found_in_envmap_dirs(tmp_path: Path) -> None:
    root = write_synthetic_dataset(tmp_path / "d", objects=1, views=1, lightings=3)
    moved = tmp_path / "moved"
    (root / "envmaps").rename(moved)
    with pytest.raises(DataError):
        RelightTrainDataset([root], _cfg(root, max_load_retries=1), 16)[0]
    assert (
        RelightTrainDataset([root], _cfg(root, envmap_dirs=(moved,)), 16)[0].envmaps.shape[0] == 2
    )


def test_batched_lighting_matches_one_by_one(root: Path) -> None:
    from gaffer_diffusion.conditioning import LIGHTING_FILTER, LIGHTING_SUPERSAMPLE
    from gaffer_envmap.encode import encode_lighting

    ds = RelightTrainDataset([root], _cfg(root), 16)
    batch = collate_items([ds[0], ds[1]])
    env = batch.envmaps.flatten(0, 1)
    w2c = batch.w2c_blender.repeat_interleave(2, dim=0)
    ldr, hdr = encode_batch_lighting(env, w2c, size=16, compat="default")
    for i in range(4):
        one = encode_lighting(
            env[i].numpy(),
            w2c[i].double().numpy(),
            size=16,
            filter=LIGHTING_FILTER,  # the model's filter, not the library default
            supersample=LIGHTING_SUPERSAMPLE,
        )
        torch.testing.assert_close(ldr[i], one.ldr[0], atol=1e-5, rtol=0)
        torch.testing.assert_close(hdr[i], one.hdr[0], atol=1e-5, rtol=0)


def test_extreme_hdr_maps_give_finite_conditioning(tmp_path: Path) -> None:
    root = write_synthetic_dataset(
        tmp_path / "d", objects=1, views=1, lightings=3, envmaps=1, sun_peak=1e38
    )
    ds = RelightTrainDataset([root], _cfg(root), 16)
    item = ds[0]
    assert float(item.envmaps.max()) <= 1.0001e30  # clamped to `data.max_radiance`
    ldr, hdr = encode_batch_lighting(
        item.envmaps, item.w2c_blender[None].expand(2, 3, 4), size=16, compat="default"
    )
    assert torch.isfinite(ldr).all() and torch.isfinite(hdr).all() and float(hdr.max()) <= 1.0


def test_cfg_dropout_frequencies() -> None:
    r = torch.rand(200_000, generator=torch.Generator().manual_seed(0))
    clip, lat = cfg_dropout_masks(r, 0.05)
    only_clip, both, only_lat = (
        (clip & ~lat).float().mean(),
        (clip & lat).float().mean(),
        (lat & ~clip).float().mean(),
    )
    for f in (only_clip, both, only_lat):
        assert abs(float(f) - 0.05) < 0.003
