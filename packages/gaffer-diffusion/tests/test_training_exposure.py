"""Exposure and tint augmentation of targets (`DataConfig.target_exposure_stops`, `target_tint_stops`)."""

from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("gaffer_data")

from gaffer_diffusion.training import DataConfig, RelightTrainDataset
from gaffer_diffusion.training.config import ConfigError
from gaffer_diffusion.training.exposure import exposure_gains, reexpose_on_white
from gaffer_diffusion.training.testing import write_synthetic_dataset


def _srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)


def test_reexposure_matches_rendering_linear_light() -> None:
    rng = np.random.default_rng(0)
    radiance = rng.uniform(0.0, 0.45, (3, 8, 8))  # an unclipped render, linear
    alpha = torch.ones(1, 8, 8)
    alpha[:, :2] = 0.0  # background rows: white whatever the gain
    img = torch.from_numpy(_srgb(radiance)).float() * alpha + (1 - alpha)
    for gain in ([0.5] * 3, [2.0] * 3, [3.0, 1.0, 0.25]):
        g = np.asarray(gain)[:, None, None]
        want = torch.from_numpy(_srgb(np.clip(radiance * g, 0, 1))).float()
        got = reexpose_on_white(img, alpha, torch.tensor(gain))
        assert torch.allclose(got[:, 2:], want[:, 2:], atol=2e-5)
        assert torch.equal(got[:, :2], torch.ones(3, 2, 8))


def test_darkening_a_clipped_target_turns_into_brightening() -> None:
    alpha = torch.ones(1, 4, 4)
    clipped = torch.full((3, 4, 4), 0.5)
    clipped[0, 1, 1] = 1.0
    down = torch.full((3,), -1.5)
    assert exposure_gains(down, clipped, alpha).tolist() == pytest.approx(
        [2**1.5, 2**-1.5, 2**-1.5]
    )
    assert exposure_gains(down, torch.full((3, 4, 4), 0.5), alpha).tolist() == pytest.approx(
        [2**-1.5] * 3
    )
    # a clipped pixel on the background does not count
    bg = torch.full((3, 4, 4), 0.5)
    a = alpha.clone()
    a[:, 0, 0] = 0.0
    bg[:, 0, 0] = 1.0
    assert exposure_gains(torch.full((3,), -1.0), bg, a).tolist() == pytest.approx([0.5] * 3)
    with pytest.raises(ValueError, match="gains"):
        reexpose_on_white(bg, a, torch.tensor([1.0, 0.0, 1.0]))


def test_dataset_scales_map_and_render_together(tmp_path: Path) -> None:
    root = write_synthetic_dataset(tmp_path / "d", objects=1, views=1, lightings=3)
    base = RelightTrainDataset([root], DataConfig(root=root, envmap_height=8), 16)
    aug = RelightTrainDataset(
        [root],
        DataConfig(root=root, envmap_height=8, target_exposure_stops=1.5, target_tint_stops=0.5),
        16,
    )
    changed = 0
    for key in range(6):
        a, b = base[key], aug[key]
        assert torch.equal(a.input_image, b.input_image)  # the input is never touched
        assert a.envmaps is not None and b.envmaps is not None
        for j in range(a.envmaps.shape[0]):
            for c in range(3):
                ratio = (b.envmaps[j, ..., c].sum() / a.envmaps[j, ..., c].sum()).item()
                assert 2**-2 - 1e-4 <= ratio <= 2**2 + 1e-4
                brighter = b.target_images[j, c].mean() >= a.target_images[j, c].mean() - 1e-6
                assert bool(brighter) == (ratio >= 1.0)
                changed += abs(ratio - 1.0) > 1e-3
    assert changed > 0


def test_exposure_stops_range_is_checked(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"data\.target_exposure_stops"):
        DataConfig(root=tmp_path, target_exposure_stops=-1.0)
    with pytest.raises(ConfigError, match=r"data\.target_tint_stops"):
        DataConfig(root=tmp_path, target_tint_stops=float("nan"))
