"""The training loop: exact resume, frozen parts, checkpoints (atomic, rotated, SIGTERM), NaN handling,
logging and validation, the CLI. Tiny random-init model, 32 px synthetic renders, CPU."""

import json
import os
import signal
from pathlib import Path
from typing import Any

import pytest
import torch

pytest.importorskip("gaffer_data")
pytest.importorskip("accelerate")

from gaffer_diffusion.training import (
    ResumeError,
    TrainingDivergedError,
    load_checkpoint_model,
    train,
)
from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training import loop as loop_mod
from gaffer_diffusion.training.testing import tiny_train_config, write_synthetic_dataset
from gaffer_diffusion.training.tracking import read_log

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("train") / "data", objects=3, views=2, lightings=3
    )


_config = tiny_train_config


def test_resume_gives_the_same_loss_curve(tmp_path: Path, data_root: Path) -> None:
    straight = train(_config(tmp_path / "a", data_root, train={"max_steps": 6}))
    first = train(
        _config(tmp_path / "b", data_root, train={"max_steps": 3}, checkpoint={"every_steps": 3})
    )
    assert first.step == 3 and first.checkpoint is not None
    second = train(_config(tmp_path / "b", data_root, train={"max_steps": 6}), resume=True)
    assert second.start_step == 3 and second.step == 6
    resumed = first.losses + second.losses
    assert len(resumed) == len(straight.losses) == 6
    torch.testing.assert_close(
        torch.tensor(resumed), torch.tensor(straight.losses), rtol=1e-6, atol=1e-7
    )
    a = load_checkpoint_model(straight.checkpoint)
    b = load_checkpoint_model(second.checkpoint)
    for (n, pa), (_, pb) in zip(a.unet.named_parameters(), b.unet.named_parameters(), strict=True):
        torch.testing.assert_close(pa, pb, rtol=1e-5, atol=1e-6, msg=n)
    rows = read_log(tmp_path / "b" / "logs" / "train.jsonl")
    assert [r["step"] for r in rows] == [1, 2, 3, 4, 5, 6]
    assert {"loss", "lr", "samples_per_s", "data_wait_share", "grad_norm"} <= set(rows[-1])


def test_only_the_unet_trains(
    tmp_path: Path, data_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    built: list[Any] = []
    real = loop_mod.build_training_model

    def spy(source):
        m = real(source)
        built.append(
            (
                m,
                {k: v.clone() for k, v in m.vae.state_dict().items()},
                {k: v.clone() for k, v in m.image_encoder.state_dict().items()},
                {k: v.clone() for k, v in m.unet.state_dict().items()},
            )
        )
        return m

    monkeypatch.setattr(loop_mod, "build_training_model", spy)
    cfg = _config(
        tmp_path / "r",
        data_root,
        train={"max_steps": 2, "grad_accum": 2, "gradient_checkpointing": True},
        optim={"max_grad_norm": 0.5},
    )
    result = train(cfg)
    model, vae0, clip0, unet0 = built[0]
    assert all(torch.equal(v, vae0[k]) for k, v in model.vae.state_dict().items())
    assert all(torch.equal(v, clip0[k]) for k, v in model.image_encoder.state_dict().items())
    assert not any(p.requires_grad for p in model.vae.parameters())
    assert not any(p.requires_grad for p in model.image_encoder.parameters())
    assert any(not torch.equal(v, unet0[k]) for k, v in model.unet.state_dict().items())
    assert result.final_model is not None and (result.final_model / "gaffer_model.json").is_file()
    assert all(torch.isfinite(torch.tensor(result.losses)))


def test_checkpoints_rotate_and_a_crash_while_saving_keeps_the_last(
    tmp_path: Path, data_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "run"
    train(_config(out, data_root, train={"max_steps": 6}, checkpoint={"every_steps": 1, "keep": 2}))
    steps = [s for s, _ in ckpt.list_checkpoints(out / "checkpoints")]
    assert steps == [5, 6]
    # a writer killed before its rename leaves only a temporary folder: the latest stays step 6
    real_replace = os.replace

    def crash(src, dst):
        if ".tmp-checkpoint-" in str(src):
            raise KeyboardInterrupt("killed while publishing")
        return real_replace(src, dst)

    monkeypatch.setattr(ckpt.os, "replace", crash)
    with pytest.raises(KeyboardInterrupt):
        train(_config(out, data_root, train={"max_steps": 7}), resume=True)
    monkeypatch.setattr(ckpt.os, "replace", real_replace)
    assert any(p.name.startswith(".tmp-checkpoint-") for p in (out / "checkpoints").iterdir())
    assert ckpt.read_state(ckpt.latest_checkpoint(out / "checkpoints")).step == 6
    result = train(_config(out, data_root, train={"max_steps": 7}), resume=True)
    assert result.start_step == 6 and result.step == 7
    assert not any(p.name.startswith(".tmp-") for p in (out / "checkpoints").iterdir())


def test_sigterm_saves_and_stops(tmp_path: Path, data_root: Path) -> None:
    def on_step(step: int, loss: float) -> None:
        if step == 1:
            os.kill(os.getpid(), signal.SIGTERM)

    result = train(
        _config(tmp_path / "s", data_root, train={"max_steps": 5}, checkpoint={"every_steps": 100}),
        on_step=on_step,
    )
    assert result.stop_reason == "sigterm" and result.step == 1
    assert ckpt.read_state(result.checkpoint).step == 1 and result.final_model is None
    assert signal.getsignal(signal.SIGTERM) is not None


def test_a_failing_end_training_is_logged_and_counted_and_a_bug_there_propagates(
    tmp_path: Path,
    data_root: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    # every exception around end_training() was suppressed; now only the teardown's own
    # failures (RuntimeError from torch.distributed, OSError from a tracker) are, logged and counted
    from accelerate import Accelerator

    def teardown_fails(self) -> None:
        raise RuntimeError("process group already destroyed")

    monkeypatch.setattr(Accelerator, "end_training", teardown_fails)
    caplog.set_level("WARNING", logger=loop_mod.__name__)
    result = train(_config(tmp_path / "e", data_root, train={"max_steps": 1}))
    assert result.end_training_errors == 1 and result.step == 1
    assert result.final_model is not None and result.final_model.is_dir()
    assert any("process group already destroyed" in r.getMessage() for r in caplog.records)

    def bug(self) -> None:
        raise TypeError("a bug, not a teardown failure")

    monkeypatch.setattr(Accelerator, "end_training", bug)
    with pytest.raises(TypeError, match="a bug"):
        train(_config(tmp_path / "f", data_root, train={"max_steps": 1}))
    monkeypatch.undo()
    assert (
        train(_config(tmp_path / "g", data_root, train={"max_steps": 1})).end_training_errors == 0
    )


def test_fresh_start_over_checkpoints_and_resume_without_any_are_refused(
    tmp_path: Path, data_root: Path
) -> None:
    with pytest.raises(ResumeError, match="holds no complete checkpoint"):
        train(_config(tmp_path / "x", data_root), resume=True)
    train(_config(tmp_path / "y", data_root, train={"max_steps": 1}))
    with pytest.raises(ResumeError, match="pass `--resume`"):
        train(_config(tmp_path / "y", data_root, train={"max_steps": 2}))


def test_nan_steps_are_skipped_then_training_stops_with_a_usable_checkpoint(
    tmp_path: Path, data_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = loop_mod.build_training_model
    calls = {"n": 0}

    def poisoned(source):
        m = real(source)

        def hook(module, args, output):
            calls["n"] += 1
            if calls["n"] > 2:  # forward passes 3, 4, ...: an fp16-style overflow
                output.sample.fill_(float("nan"))
            return output

        m.unet.register_forward_hook(hook)
        return m

    monkeypatch.setattr(loop_mod, "build_training_model", poisoned)
    cfg = _config(
        tmp_path / "n",
        data_root,
        train={"max_steps": 10, "max_consecutive_nonfinite": 3},
        checkpoint={"every_steps": 100},
    )
    with pytest.raises(TrainingDivergedError, match="3 consecutive steps") as info:
        train(cfg)
    err = info.value
    assert err.step == 5 and Path(err.checkpoint).is_dir()
    state = ckpt.read_state(err.checkpoint)
    assert state.skipped_steps == 3 and state.consecutive_nonfinite == 3
    model = load_checkpoint_model(err.checkpoint, use_ema=False)
    assert all(torch.isfinite(p).all() for p in model.unet.parameters())


def test_bf16_with_extreme_hdr_maps_stays_finite(tmp_path: Path) -> None:
    root = write_synthetic_dataset(
        tmp_path / "d", objects=2, views=1, lightings=3, envmaps=1, sun_peak=1e38
    )
    cfg = _config(
        tmp_path / "o",
        root,
        train={"max_steps": 2, "mixed_precision": "bf16"},
        data={"val_objects": 0},
    )
    result = train(cfg)
    assert result.skipped_steps == 0 and all(torch.isfinite(torch.tensor(result.losses)))


def test_bf16_on_a_cpu_without_native_bf16_trains_in_fp32(
    tmp_path: Path,
    data_root: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    # emulated bf16 is ~30x slower than fp32 on AVX2-only CPUs (CI's smoke training did 2 steps in 3
    # minutes); the loop must fall back to fp32 and say so
    monkeypatch.setattr(loop_mod, "cpu_has_bf16", lambda: False)
    monkeypatch.setattr(loop_mod, "_gpu_available", lambda: False)
    seen: list[str] = []
    real = loop_mod._make_accelerator

    def spy(config: Any) -> Any:
        acc = real(config)
        seen.append(str(acc.mixed_precision))
        return acc

    monkeypatch.setattr(loop_mod, "_make_accelerator", spy)
    cfg = _config(tmp_path / "o", data_root, train={"max_steps": 1, "mixed_precision": "bf16"})
    with caplog.at_level("WARNING", logger=loop_mod.logger.name):
        train(cfg)
    assert seen == ["no"]
    assert "training in fp32 instead" in caplog.text


def test_validation_reports_psnr_and_identity_baseline(tmp_path: Path, data_root: Path) -> None:
    cfg = _config(
        tmp_path / "v",
        data_root,
        train={"max_steps": 2},
        validation={"every_steps": 1, "num_samples": 2, "num_inference_steps": 2, "batch_size": 2},
    )
    result = train(cfg)
    assert [v.step for v in result.validations] == [1, 2]
    v = result.validations[-1]
    assert v.sheet is not None and v.sheet.is_file() and len(v.psnr_per_item) == 2
    assert 0 < v.psnr < 100
    rows = read_log(tmp_path / "v" / "logs" / "train.jsonl", kind="validation")
    assert [r["step"] for r in rows] == [1, 2] and "psnr_identity" in rows[0]


def test_cli_train(tmp_path: Path, data_root: Path) -> None:
    from gaffer_diffusion.cli import main

    cfg = _config(tmp_path / "c", data_root, train={"max_steps": 2})
    path = tmp_path / "c.json"
    path.write_text(json.dumps(cfg.to_dict()))
    assert main(["train", "--config", str(path)]) == 0
    cfg2 = _config(tmp_path / "c", data_root, train={"max_steps": 3})
    path.write_text(json.dumps(cfg2.to_dict()))
    assert main(["train", "--config", str(path), "--resume"]) == 0
    assert ckpt.read_state(ckpt.latest_checkpoint(tmp_path / "c" / "checkpoints")).step == 3
    assert main(["train", "--config", str(tmp_path / "missing.json")]) == 2


def test_timestep_range_limits_the_training_timesteps(
    tmp_path: Path, data_root: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gaffer_diffusion.errors import ConfigError

    seen: list[int] = []
    original = loop_mod._Trainer.loss

    def spy(self: Any, unet: Any, batch: Any, gen: torch.Generator) -> torch.Tensor:
        forward = unet.forward

        def record(sample: torch.Tensor, timestep: torch.Tensor, *a: Any, **k: Any) -> Any:
            seen.extend(torch.as_tensor(timestep).flatten().tolist())
            return forward(sample, timestep, *a, **k)

        unet.forward = record
        try:
            return original(self, unet, batch, gen)
        finally:
            del unet.forward

    monkeypatch.setattr(loop_mod._Trainer, "loss", spy)
    train(
        _config(tmp_path / "late", data_root, train={"max_steps": 3, "timestep_range": [990, 999]})
    )
    assert seen and all(990 <= t <= 999 for t in seen)
    with pytest.raises(ConfigError, match=r"train\.timestep_range"):
        _config(tmp_path / "bad", data_root, train={"timestep_range": [500, 100]})
    with pytest.raises(ConfigError, match=r"train\.timestep_range"):
        train(_config(tmp_path / "big", data_root, train={"timestep_range": [0, 1000]}))


def test_mirror_views_flip_a_view_with_its_targets_and_maps(
    tmp_path: Path, data_root: Path
) -> None:
    from gaffer_diffusion.errors import ConfigError
    from gaffer_envmap.augment import mirror_camera_x

    g = torch.Generator().manual_seed(0)
    b, t = 64, 2
    inputs, ldr = torch.rand(b, 3, 4, 8, generator=g), torch.rand(b * t, 3, 4, 8, generator=g)
    targets, hdr = torch.rand(b * t, 3, 4, 8, generator=g), torch.rand(b * t, 3, 4, 8, generator=g)
    out = loop_mod._mirror_views(
        inputs, targets, ldr, hdr, t, 0.5, torch.Generator().manual_seed(1)
    )
    flipped = [bool(torch.equal(out[0][i], inputs[i].flip(-1))) for i in range(b)]
    assert 10 < sum(flipped) < 54  # about half the views
    for i, f in enumerate(flipped):
        if not f:
            assert torch.equal(out[0][i], inputs[i])
        for k in range(i * t, i * t + t):  # every target of a view follows its input
            assert torch.equal(out[1][k], targets[k].flip(-1) if f else targets[k])
            assert torch.equal(out[2][k], mirror_camera_x(ldr[k : k + 1])[0] if f else ldr[k])
            assert torch.equal(out[3][k], mirror_camera_x(hdr[k : k + 1])[0] if f else hdr[k])
    assert len(out) == 5 and out[4] is None  # no alphas in, none out
    # with alphas: each mask flips with its view, under the same draws
    alphas = (torch.rand(b, 1, 4, 8, generator=g) > 0.5).float()
    out_a = loop_mod._mirror_views(
        inputs, targets, ldr, hdr, t, 0.5, torch.Generator().manual_seed(1), alphas
    )
    assert len(out_a) == 5
    for k in range(4):
        assert torch.equal(out_a[k], out[k])
    assert out_a[4] is not None and out_a[4].shape == alphas.shape
    for i, f in enumerate(flipped):
        assert torch.equal(out_a[4][i], alphas[i].flip(-1) if f else alphas[i])
    # training runs with it, and the probability is validated
    result = train(
        _config(tmp_path / "mirror", data_root, data={"mirror_prob": 0.5}, train={"max_steps": 2})
    )
    assert result.step == 2
    with pytest.raises(ConfigError, match=r"data\.mirror_prob"):
        _config(tmp_path / "bad", data_root, data={"mirror_prob": 1.5})
