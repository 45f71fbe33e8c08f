import json

import pytest
import torch

from gaffer_diffusion import (
    CheckpointMismatchError,
    CheckpointNotFoundError,
    RelightPipeline,
    SamplingConfig,
)
from gaffer_diffusion.loading import (
    load_authors_release,
    load_pretrained,
    load_zero123_xl,
    model_config_matches,
    read_state_dict,
    resolve_authors_checkpoint,
    save_pretrained,
)
from gaffer_diffusion.testing import (
    random_conditions,
    tiny_model,
    write_fake_authors_checkpoint,
    write_fake_zero123,
)

FAST = SamplingConfig(num_inference_steps=2)


@pytest.fixture(scope="module")
def reference():
    model = tiny_model(seed=7)
    cond = random_conditions(2)
    images = RelightPipeline(model)(cond, FAST, seeds=[0, 1]).images
    return model, cond, images


@pytest.fixture(scope="module")
def release(tmp_path_factory, reference):
    model = reference[0]
    root = tmp_path_factory.mktemp("release")
    base = write_fake_zero123(model, root / "zero123-xl")
    ckpt = write_fake_authors_checkpoint(model, root / "ckpt" / "checkpoint-80000")
    return base, ckpt


@pytest.mark.parametrize("file_format", ["safetensors", "bin"])
def test_authors_release_is_bit_identical_to_direct_construction(
    tmp_path, reference, release, file_format
) -> None:
    model, cond, images = reference
    base, _ = release
    ckpt = write_fake_authors_checkpoint(
        model, tmp_path / "checkpoint-80000", file_format=file_format
    )
    result = load_authors_release(tmp_path, base)  # the parent folder is accepted too
    assert result.report.ok, result.report.summary()
    assert result.model.unet.config.in_channels == 16
    assert model_config_matches(result.model.config, model.config)
    assert resolve_authors_checkpoint(tmp_path) == ckpt / (
        "model.safetensors" if file_format == "safetensors" else "pytorch_model.bin"
    )
    out = RelightPipeline(result.model)(cond, FAST, seeds=[0, 1]).images
    assert torch.equal(out, images)


def test_mismatched_checkpoint_is_reported(tmp_path, reference, release) -> None:
    model, _, _ = reference
    base, ckpt = release
    state = read_state_dict(ckpt / "model.safetensors")
    state["conv_in.weight"] = state["conv_in.weight"][
        :, :8
    ].contiguous()  # a Zero123-shaped conv_in
    del state["conv_out.bias"]
    state["cc_projection.weight"] = torch.zeros(2, 2)
    bad = tmp_path / "checkpoint-80000"
    bad.mkdir()
    torch.save(state, bad / "pytorch_model.bin")
    with pytest.raises(CheckpointMismatchError, match=r"conv_in\.weight") as info:
        load_authors_release(bad, base)
    assert "strict=False" in str(info.value)
    result = load_authors_release(bad, base, strict=False)
    r = result.report
    assert r.missing == ("conv_out.bias",)
    assert r.unexpected == ("cc_projection.weight",)
    assert [(m.name, m.expected, m.actual) for m in r.mismatched] == [
        ("conv_in.weight", (32, 16, 3, 3), (32, 8, 3, 3))
    ]
    assert not r.ok and "missing (1)" in r.summary()
    # matching tensors were still loaded
    assert torch.equal(result.model.unet.conv_out.weight, model.unet.conv_out.weight)


def test_wrapper_prefix_is_stripped(tmp_path, reference, release) -> None:
    model, _, _ = reference
    base, _ = release
    folder = tmp_path / "checkpoint-80000"
    folder.mkdir()
    torch.save(
        {f"module.{k}": v for k, v in model.unet.state_dict().items()}, folder / "pytorch_model.bin"
    )
    result = load_authors_release(folder, base)
    assert result.report.ok and result.report.stripped_prefix == "module."


def test_missing_files_name_the_file_where_and_how(tmp_path, release) -> None:
    base, ckpt = release
    with pytest.raises(CheckpointNotFoundError, match=r"model\.safetensors") as info:
        load_authors_release(tmp_path, base)
    msg = str(info.value)
    assert str(tmp_path) in msg and "neural_gaffer_res256_ckpt.zip" in msg
    assert isinstance(info.value, FileNotFoundError)
    with pytest.raises(CheckpointNotFoundError, match="base model folder"):
        load_authors_release(ckpt, tmp_path / "nowhere")
    empty = tmp_path / "base"
    (empty / "unet").mkdir(parents=True)
    with pytest.raises(CheckpointNotFoundError, match=r"unet/config\.json") as info:
        load_authors_release(ckpt, empty)
    assert "Zero-1-to-3 XL" in str(info.value)


def test_zero123_surgery(release) -> None:
    base, _ = release
    result = load_zero123_xl(base)
    w = result.model.unet.conv_in.weight
    assert w.shape == (32, 16, 3, 3) and torch.count_nonzero(w[:, 8:]) == 0
    assert result.model.unet.config.in_channels == 16
    assert any("8 -> 16" in n for n in result.report.notes)
    zero123_unet = read_state_dict(base / "unet" / "diffusion_pytorch_model.safetensors")
    assert torch.equal(w[:, :8], zero123_unet["conv_in.weight"])
    assert torch.equal(result.model.unet.conv_in.bias, zero123_unet["conv_in.bias"])


def test_own_format_round_trip(tmp_path, reference) -> None:
    model, cond, images = reference
    save_pretrained(model, tmp_path / "ours")
    cfg = json.loads((tmp_path / "ours" / "unet" / "config.json").read_text())
    assert cfg["in_channels"] == 16
    manifest = json.loads((tmp_path / "ours" / "gaffer_model.json").read_text())
    assert manifest["schema"] == "gaffer.diffusion_model" and manifest["config"]["name"] == "tiny"
    result = load_pretrained(tmp_path / "ours")
    assert result.model.config == model.config
    assert torch.equal(RelightPipeline(result.model)(cond, FAST, seeds=[0, 1]).images, images)
    manifest["schema_version"] = "2.0"
    (tmp_path / "ours" / "gaffer_model.json").write_text(json.dumps(manifest))
    with pytest.raises(CheckpointMismatchError, match="schema_version"):
        load_pretrained(tmp_path / "ours")
    (tmp_path / "ours" / "gaffer_model.json").unlink()
    with pytest.raises(CheckpointNotFoundError, match=r"gaffer_model\.json"):
        load_pretrained(tmp_path / "ours")


def test_corrupt_weights_file(tmp_path, release) -> None:
    base, _ = release
    folder = tmp_path / "checkpoint-80000"
    folder.mkdir()
    (folder / "model.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(CheckpointMismatchError, match="Could not read"):
        load_authors_release(folder, base)


@pytest.mark.weights
def test_real_release_loads(tmp_path) -> None:
    import os

    ckpt = os.environ.get("GAFFER_NEURAL_GAFFER_CKPT")
    base = os.environ.get("GAFFER_ZERO123_XL")
    if not ckpt or not base:
        pytest.skip("set GAFFER_NEURAL_GAFFER_CKPT and GAFFER_ZERO123_XL to local folders")
    result = load_authors_release(ckpt, base)
    assert result.report.ok
    assert result.model.unet.conv_in.weight.shape == (320, 16, 3, 3)
