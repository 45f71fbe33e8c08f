"""Training on the authors' released layout after `gaffer-data convert-authors`: items use
their pre-encoded LDR/HDR maps as they are (resized like evaluation does), batches mix them with
gaffer-data renders, and the tiny preset trains, validates and resumes on a converted split. CPU.

A cross-package test (gaffer-data's converter feeds gaffer-diffusion's training): moved here unchanged
from gaffer-diffusion's tests/test_training_authors.py."""

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image

pytest.importorskip("gaffer_data")

from gaffer_diffusion.training import (
    DataConfig,
    DataError,
    RelightTrainDataset,
    batch_lighting,
    collate_items,
    encode_batch_lighting,
    load_checkpoint_model,
    train,
)
from gaffer_diffusion.training.dataset import batch_lighting_of, load_image_on_white
from gaffer_diffusion.training.testing import (
    tiny_train_config,
    write_authors_release,
    write_synthetic_dataset,
)

RES = 16  # model resolution of the dataset tests; the authors' maps are 24 px, the images 32 px


@pytest.fixture(autouse=True)
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from gaffer_data.convert import convert_authors

    base = tmp_path_factory.mktemp("authors")
    release = write_authors_release(base / "val_unseen", objects=3, views=2, lightings=3)
    out = base / "converted"
    summary = convert_authors(release, out)
    assert not summary.failed and len(summary.converted) == 3
    return out


@pytest.fixture(scope="module")
def render_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("render") / "data", objects=2, views=2, lightings=3
    )


def _map(path: Path, size: int) -> torch.Tensor:
    """The PNG as RGB in [0, 1], resized with PIL bilinear (evaluation's reader), `[3, S, S]`."""
    with Image.open(path) as im:
        rgb = im.convert("RGB").resize((size, size), Image.Resampling.BILINEAR)
    return torch.from_numpy(np.asarray(rgb, np.float32) / 255.0).permute(2, 0, 1)


def test_items_of_a_converted_split_carry_the_authors_maps(converted: Path) -> None:
    from gaffer_data.dataset import read_authors_object

    ds = RelightTrainDataset([converted], DataConfig(root=converted, area_light_prob=0.5), RES)
    assert len(ds) == 6 and ds.object_ids == ("obj0", "obj1", "obj2")
    seen_area = seen_lit = False
    for key in range(12):
        item = ds[key]
        assert item.envmaps is None and item.lighting_encoded
        assert item.encoded_ldr is not None and item.encoded_hdr is not None
        assert item.target_images.shape == (2, 3, RES, RES) == item.encoded_ldr.shape
        obj = read_authors_object(converted / "objects" / item.object_id)
        view = next(v for v in obj.views if v.index == item.view_index)
        np.testing.assert_allclose(
            item.w2c_blender.numpy(), obj.poses().w2c_blender[view.row], rtol=0, atol=1e-6
        )
        images = {li.lighting_index: load_image_on_white(obj.path(li.png), RES) for li in view.lit}
        used = []
        for k in range(2):
            # which lighting is target k: its image, then its maps must be the authors' PNGs resized
            match = [i for i, im in images.items() if torch.equal(im, item.target_images[k])]
            assert len(match) == 1
            lit = next(li for li in view.lit if li.lighting_index == match[0])
            torch.testing.assert_close(item.encoded_ldr[k], _map(obj.path(lit.envmap_ldr), RES))
            torch.testing.assert_close(item.encoded_hdr[k], _map(obj.path(lit.envmap_hdr), RES))
            used.append(match[0])
        assert len(set(used)) == 2
        if item.input_is_area:
            seen_area = True
            assert view.area_png is not None
            assert torch.equal(item.input_image, load_image_on_white(obj.path(view.area_png), RES))
        else:
            seen_lit = True
            rest = [i for i in images if i not in used]
            assert torch.equal(item.input_image, images[rest[0]])
    assert seen_area and seen_lit
    # the item depends only on (seed, key)
    assert torch.equal(ds[5].encoded_hdr, ds[5].encoded_hdr)  # type: ignore[arg-type]


def test_mixed_batch_lighting_keeps_each_kind(converted: Path, render_root: Path) -> None:
    cfg = DataConfig(root=render_root, envmap_height=8, lighting_compat="neural-gaffer")
    ds = RelightTrainDataset([render_root, converted], cfg, RES)
    assert len(ds) == 4 + 6
    items = [ds[0], ds[5], ds[1], ds[9]]  # render, authors, render, authors
    assert [i.lighting_encoded for i in items] == [False, True, False, True]
    batch = collate_items(items)
    assert batch.envmaps.shape == (2, 2, 8, 16, 3) and batch.encoded_ldr is not None
    assert batch.encoded_ldr.shape == (2, 2, 3, RES, RES)
    assert batch.lighting_encoded is not None
    assert batch.lighting_encoded.tolist() == [False, True, False, True]
    ldr, hdr = batch_lighting_of(batch, size=RES, compat="neural-gaffer")
    assert ldr.shape == hdr.shape == (8, 3, RES, RES)
    for b, item in enumerate(items):
        rows = slice(2 * b, 2 * b + 2)
        if item.envmaps is None:
            assert torch.equal(ldr[rows], item.encoded_ldr) and torch.equal(
                hdr[rows], item.encoded_hdr
            )
        else:
            ref_l, ref_h = encode_batch_lighting(
                item.envmaps,
                item.w2c_blender[None].expand(2, 3, 4),
                size=RES,
                compat="neural-gaffer",
            )
            torch.testing.assert_close(ldr[rows], ref_l)
            torch.testing.assert_close(hdr[rows], ref_h)
    # a batch of renders only: unchanged layout (envmaps for every item, no encoded maps)
    renders = collate_items([ds[0], ds[1]])
    assert renders.lighting_encoded is None and renders.encoded_ldr is None
    assert renders.envmaps.shape[0] == 2


def test_bad_input_names_the_argument_and_the_fix(
    converted: Path, render_root: Path, tmp_path: Path
) -> None:
    with pytest.raises(DataError, match=r"data\.lighting_compat"):
        RelightTrainDataset([render_root, converted], DataConfig(root=render_root), RES)
    with pytest.raises(DataError, match="convert-authors"):
        RelightTrainDataset([tmp_path / "nothing"], DataConfig(root=tmp_path), RES)
    with pytest.raises(DataError, match="list"):
        RelightTrainDataset(converted, DataConfig(root=converted), RES)  # type: ignore[arg-type]
    with pytest.raises(DataError, match="targets_per_sample"):
        RelightTrainDataset([converted], DataConfig(root=converted, targets_per_sample=4), RES)
    item = RelightTrainDataset([converted], DataConfig(root=converted), RES)[0]
    with pytest.raises(DataError, match="either `envmaps`"):
        type(item)(**{**item.__dict__, "encoded_hdr": None})
    with pytest.raises(DataError, match="resolution"):
        batch_lighting(
            torch.zeros(0, 4, 8, 3),
            torch.zeros(1, 3, 4),
            encoded=torch.tensor([True]),
            encoded_ldr=torch.zeros(1, 3, 8, 8),
            encoded_hdr=torch.zeros(1, 3, 8, 8),
            size=RES,
            compat="neural-gaffer",
        )


_config = tiny_train_config


def test_tiny_training_on_a_converted_split_validates_and_resumes(
    converted: Path, tmp_path: Path
) -> None:
    val = {"every_steps": 2, "num_samples": 2, "num_inference_steps": 2, "batch_size": 2}
    straight = train(_config(tmp_path / "a", converted, validation=val))
    assert straight.step == 4 and straight.skipped_samples == 0 and straight.skipped_steps == 0
    assert all(np.isfinite(straight.losses))
    assert [v.step for v in straight.validations] == [2, 4]
    assert all(0 < v.psnr < 100 and len(v.psnr_per_item) == 2 for v in straight.validations)
    assert (
        straight.final_model is not None and (straight.final_model / "gaffer_model.json").is_file()
    )
    first = train(_config(tmp_path / "b", converted, train={"max_steps": 2}, validation=val))
    second = train(_config(tmp_path / "b", converted, validation=val), resume=True)
    assert second.start_step == 2 and second.step == 4
    torch.testing.assert_close(
        torch.tensor(first.losses + second.losses),
        torch.tensor(straight.losses),
        rtol=1e-6,
        atol=1e-7,
    )
    a = load_checkpoint_model(straight.checkpoint)
    b = load_checkpoint_model(second.checkpoint)
    for (n, pa), (_, pb) in zip(a.unet.named_parameters(), b.unet.named_parameters(), strict=True):
        torch.testing.assert_close(pa, pb, rtol=1e-5, atol=1e-6, msg=n)


def test_renders_train_with_a_converted_val_root(
    converted: Path, render_root: Path, tmp_path: Path
) -> None:
    val = {"every_steps": 1, "num_samples": 3, "num_inference_steps": 1, "batch_size": 2}
    data = {"val_root": str(converted), "lighting_compat": "neural-gaffer"}
    result = train(
        _config(tmp_path / "m", render_root, data=data, train={"max_steps": 1}, validation=val)
    )
    assert result.step == 1 and [v.step for v in result.validations] == [1]
    assert len(result.validations[0].psnr_per_item) == 3
    with pytest.raises(DataError, match=r"data\.lighting_compat"):
        train(_config(tmp_path / "d", render_root, data={"val_root": str(converted)}))


def test_extra_roots_mix_renders_and_a_converted_split_in_one_run(
    converted: Path, render_root: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gaffer_diffusion.training import loop as loop_mod

    built: list[RelightTrainDataset] = []

    class Spy(RelightTrainDataset):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            built.append(self)

    monkeypatch.setattr(loop_mod, "RelightTrainDataset", Spy)
    data = {"extra_roots": [str(converted)], "lighting_compat": "neural-gaffer"}
    val = {"every_steps": 1, "num_samples": 2, "num_inference_steps": 1, "batch_size": 2}
    result = train(
        _config(tmp_path / "x", render_root, data=data, train={"max_steps": 2}, validation=val)
    )
    assert result.step == 2 and all(np.isfinite(result.losses))
    train_ds, val_ds = built
    kinds = {type(o).__name__ for o in train_ds.objects}
    assert kinds == {"RenderedObject", "AuthorsObject"}
    # one render object (obj0 or obj1) is held out, and the converted object with the same id is
    # left out too (no copy of a validation object trains): 1 render + 2 converted objects train
    (held,) = val_ds.object_ids
    assert held in ("obj0", "obj1") and held not in train_ds.object_ids
    assert len(train_ds.objects) == 3 and len(train_ds) == 2 + 4
    with pytest.raises(DataError, match=r"data\.lighting_compat"):
        train(_config(tmp_path / "y", render_root, data={"extra_roots": [str(converted)]}))
