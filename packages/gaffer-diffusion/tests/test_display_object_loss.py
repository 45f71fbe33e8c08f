"""`TrainLoopConfig.loss_space = "display_object"`: the one-step sample, decoded and applied to the
input, scored against the target in display space over the object (what masked PSNR measures)."""

import math
from pathlib import Path

import pytest
import torch

from gaffer_diffusion import ConfigError
from gaffer_diffusion.training.config import TrainLoopConfig
from gaffer_diffusion.training.objective import (
    DISPLAY_LOSS_FLOOR,
    _predicted_z0,
    display_object_loss,
)

pytestmark = pytest.mark.usefixtures("one_thread")


def _mse_pair(pred, target, mask, aligned):
    """Masked MSE of one pair on the [0, 1] scale, as the evaluation computes it (plain loops)."""
    p, t = (pred + 1) * 0.5, (target + 1) * 0.5
    if aligned:
        p = torch.stack([p[c] * t[c][mask].mean() / p[c][mask].mean() for c in range(3)])
    mse = (p - t).pow(2).mean(dim=0)[mask].mean()
    return mse


def test_loss_is_minus_the_mean_log_mse_raw_and_aligned_over_the_object() -> None:
    g = torch.Generator().manual_seed(0)
    pred = torch.rand(2, 3, 8, 8, generator=g) * 2 - 1
    target = torch.rand(2, 3, 8, 8, generator=g) * 2 - 1
    alpha = torch.zeros(2, 1, 8, 8)
    alpha[0, :, 2:6, 2:6] = 1.0
    alpha[1, :, :4] = 1.0
    want = []
    for i in range(2):
        m = alpha[i, 0] > 0
        raw = _mse_pair(pred[i], target[i], m, aligned=False)
        ali = _mse_pair(pred[i], target[i], m, aligned=True)
        want.append(
            0.5 * (torch.log(raw + DISPLAY_LOSS_FLOOR) + torch.log(ali + DISPLAY_LOSS_FLOOR))
        )
    torch.testing.assert_close(display_object_loss(pred, target, alpha), torch.stack(want).mean())
    # errors outside the mask cost nothing
    off = pred.clone()
    off[0, :, 0, 0] += 5.0
    torch.testing.assert_close(
        display_object_loss(off, target, alpha), display_object_loss(pred, target, alpha)
    )
    # a change of exposure moves only the raw half: the aligned half is blind to it
    scaled = (target + 1) * 0.5 * 0.5 * 2 - 1  # the target at half its brightness
    loss_scaled = display_object_loss(scaled, target, alpha)
    floor = torch.log(torch.tensor(DISPLAY_LOSS_FLOOR))
    assert float(loss_scaled) > float(floor) + 0.5
    aligned_only = (
        2 * loss_scaled
        - torch.stack(
            [
                torch.log(
                    _mse_pair(scaled[i], target[i], alpha[i, 0] > 0, False) + DISPLAY_LOSS_FLOOR
                )
                for i in range(2)
            ]
        ).mean()
    )
    torch.testing.assert_close(aligned_only, floor, atol=1e-4, rtol=0)
    # an empty mask adds ln(floor) instead of NaN
    empty = display_object_loss(pred, target, torch.zeros(2, 1, 8, 8))
    torch.testing.assert_close(empty, floor)


def test_predicted_sample_is_ddims_x0_estimate() -> None:
    from diffusers import DDIMScheduler

    from gaffer_diffusion.configs import get_preset
    from gaffer_diffusion.models.build import build_scheduler

    cfg = get_preset("gaffer-tiny").scheduler
    sched = build_scheduler(cfg)
    ddim = DDIMScheduler.from_config(sched.config)
    ddim.set_timesteps(1)
    g = torch.Generator().manual_seed(1)
    z_t, v = torch.randn(2, 4, 8, 8, generator=g), torch.randn(2, 4, 8, 8, generator=g)
    t = int(ddim.timesteps[0])
    abar = ddim.alphas_cumprod[t].view(1, 1, 1, 1)
    ours = _predicted_z0(cfg.prediction_type, v, z_t, abar)
    torch.testing.assert_close(ours, ddim.step(v, t, z_t).pred_original_sample)
    if cfg.rescale_betas_zero_snr:  # gaffer-tiny: at t = 999 the sample is -v, whatever z_t
        torch.testing.assert_close(ours, -v)


def test_refusals_name_the_setting() -> None:
    from gaffer_diffusion.training import TrainConfig

    with pytest.raises(ConfigError, match=r"loss_space"):
        TrainConfig.from_dict(
            {"output_dir": "x", "data": {"root": "y"}, "train": {"loss_space": "pixels"}}
        )
    with pytest.raises(ConfigError, match=r"residual_loss_floor.*null"):
        TrainLoopConfig(loss_space="display_object", residual_loss_floor=0.1)


def _run(tmp_path: Path, preset: str):
    pytest.importorskip("gaffer_data")
    pytest.importorskip("accelerate")
    from gaffer_diffusion.training import train as run_training
    from gaffer_diffusion.training.testing import tiny_train_config, write_synthetic_dataset

    root = write_synthetic_dataset(tmp_path / "data", objects=2, views=2, lightings=3)
    one_step = {"timestep_range": [999, 999], "loss_space": "display_object", "cfg_dropout_p": 0.0}
    cfg = tiny_train_config(
        tmp_path / "run",
        root,
        model={"preset": preset},
        train={"max_steps": 3, "ema_decay": 0.0, **one_step},
        checkpoint={"every_steps": 3, "keep": 1},
    )
    return run_training(cfg)


def test_gaffer_tiny_trains_end_to_end_on_the_display_loss(tmp_path: Path) -> None:
    result = _run(tmp_path, "gaffer-tiny")
    losses = torch.tensor(result.losses)
    assert result.step == 3 and torch.isfinite(losses).all()
    # a mean of ln(MSE + floor) on the [0, 1] scale: between ln(floor) and ln(1 + floor)
    assert bool(((losses > math.log(DISPLAY_LOSS_FLOOR)) & (losses < 0.0)).all())


def test_a_latent_model_is_refused_before_training(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"display_object.*pixel"):
        _run(tmp_path, "tiny")


def test_epsilon_prediction_is_refused() -> None:
    """Epsilon cannot give the sample at t = 999 of a zero-terminal-SNR schedule (abar = 0)."""
    from gaffer_diffusion.configs import get_preset
    from gaffer_diffusion.training.objective import _check_display_object

    model = get_preset("gaffer-tiny")
    _check_display_object(model, "v_prediction")
    with pytest.raises(ConfigError, match=r"display_object.*epsilon"):
        _check_display_object(model, "epsilon")
