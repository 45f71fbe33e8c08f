"""`check_release` / `gaffer-diffusion check` on a fake authors' release laid out as the real one."""

import json
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file, save_file

from gaffer_diffusion.cli import main
from gaffer_diffusion.loading import load_authors_release
from gaffer_diffusion.release_check import ReleaseExpectations, check_release
from gaffer_diffusion.testing import tiny_model, write_fake_authors_checkpoint, write_fake_zero123

TINY = ReleaseExpectations(conv_in_out=32, projection_dim=32)  # the tiny preset's sizes


@pytest.fixture
def release(tmp_path: Path) -> tuple[Path, Path]:
    model = tiny_model()
    base = write_fake_zero123(model, tmp_path / "zero123-xl")
    ckpt = write_fake_authors_checkpoint(model, tmp_path / "release" / "checkpoint-80000")
    return ckpt, base


def test_fake_release_mirrors_the_real_layout(release) -> None:
    ckpt, base = release
    for name in ("optimizer.bin", "scheduler.bin", "scaler.pt", "random_states_0.pkl"):
        assert (ckpt / name).is_file()
    index = json.loads((base / "model_index.json").read_text())
    assert "cc_projection" in index and (base / "cc_projection").is_dir()
    # the loader ignores the training state and the pose projection
    assert load_authors_release(ckpt, base).report.ok


def test_fake_release_passes(release) -> None:
    ckpt, base = release
    result = check_release(ckpt.parent, base, TINY)
    assert result.ok, result.report()
    text = result.report()
    assert "optimizer.bin, scheduler.bin, scaler.pt, random_states_0.pkl" in text
    assert "cc_projection" in text and "ignored" in text


def test_real_release_numbers_are_the_default(release) -> None:
    ckpt, base = release
    text = check_release(ckpt, base).report()
    assert "conv_in.weight [32, 16, 3, 3], expected [320, 16, 3, 3]" in text
    assert "CLIP projection size 32, expected 768" in text


def test_missing_parts_say_what_and_where(release) -> None:
    ckpt, base = release
    (base / "vae" / "diffusion_pytorch_model.safetensors").unlink()
    (base / "scheduler" / "scheduler_config.json").unlink()
    (ckpt / "model.safetensors").rename(ckpt / "elsewhere.safetensors")
    result = check_release(ckpt, base, TINY)
    errors = "\n".join(f.line() for f in result.errors)
    assert not result.ok and len(result.errors) == 3
    assert "missing VAE weights (`diffusion_pytorch_model.safetensors`" in errors
    assert str(base / "vae") in errors
    assert (
        f"scheduler/scheduler_config.json` (at {base / 'scheduler' / 'scheduler_config.json'})"
        in errors
    )
    assert "`model.safetensors` or `pytorch_model.bin` inside `checkpoint-80000/`" in errors
    assert "neural_gaffer_res256_ckpt.zip" in errors


def test_wrong_weights_and_configs_are_named(release) -> None:
    ckpt, base = release
    state = load_file(str(ckpt / "model.safetensors"))
    state["conv_in.weight"] = state["conv_in.weight"][:, :8].contiguous()  # Zero123's own UNet
    del state["conv_out.bias"]
    save_file({f"module.{k}": v for k, v in state.items()}, str(ckpt / "model.safetensors"))
    vae_cfg = json.loads((base / "vae" / "config.json").read_text())
    (base / "vae" / "config.json").write_text(json.dumps({**vae_cfg, "scaling_factor": 0.13025}))
    sched_path = base / "scheduler" / "scheduler_config.json"
    sched = json.loads(sched_path.read_text())
    sched_path.write_text(json.dumps({**sched, "prediction_type": "v_prediction"}))
    text = check_release(ckpt, base, TINY).report()
    assert "every key starts with 'module.'" in text
    assert "conv_in.weight [32, 8, 3, 3], expected [32, 16, 3, 3]" in text
    assert (
        "1 missing (conv_out.bias)" in text
        and "conv_in.weight [32, 8, 3, 3] vs [32, 16, 3, 3]" in text
    )
    assert "VAE scaling factor 0.13025, expected 0.18215" in text
    assert "prediction_type='v_prediction' (expected 'epsilon')" in text


def test_bin_checkpoint_is_read_as_shapes(tmp_path: Path) -> None:
    model = tiny_model()
    base = write_fake_zero123(model, tmp_path / "base")
    ckpt = write_fake_authors_checkpoint(model, tmp_path / "checkpoint-80000", file_format="bin")
    assert check_release(ckpt, base, TINY).ok
    assert isinstance(torch.load(ckpt / "pytorch_model.bin", weights_only=True), dict)


def test_cli_check_exit_codes(release, capsys) -> None:
    ckpt, base = release
    assert main(["check", "--checkpoint", str(ckpt), "--base-model", str(base)]) == 2
    out = capsys.readouterr()
    assert "expected [320, 16, 3, 3]" in out.out and "2 problem(s)" in out.out
    assert main(["check", "--checkpoint", str(ckpt), "--base-model", str(base / "nowhere")]) == 2
    assert "missing the Zero-1-to-3 XL base model folder" in capsys.readouterr().out
