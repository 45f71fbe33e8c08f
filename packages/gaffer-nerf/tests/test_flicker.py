"""`temporal_flicker`: zero for a sequence that changes as the truth does, raised by per-frame jitter."""

import pytest
import torch

from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.flicker import temporal_flicker


def _moving(t: int = 6, size: int = 16) -> torch.Tensor:
    """A smooth sequence that really changes: a gradient sliding one pixel per frame."""
    x = torch.linspace(0, 1, size * 2)
    frames = [x[k : k + size].expand(3, size, size) for k in range(t)]
    return torch.stack(frames).clone()


def test_a_constant_sequence_has_zero_flicker() -> None:
    still = torch.full((5, 3, 8, 8), 0.4)
    rep = temporal_flicker(still, still)
    assert rep.flicker == 0.0 and rep.relit_energy == 0.0 and rep.energy_ratio == pytest.approx(1)
    assert rep.frames == 5 and len(rep.per_pair) == 4 and rep.masked_fraction == 1.0


def test_following_the_truth_is_zero_and_an_offset_is_not_flicker() -> None:
    gt = _moving()
    assert temporal_flicker(gt, gt).flicker == pytest.approx(0.0, abs=1e-12)
    assert temporal_flicker((gt * 0.5 + 0.2), gt).flicker < temporal_flicker(gt.flip(0), gt).flicker
    assert temporal_flicker(gt + 0.1, gt).flicker == pytest.approx(0.0, abs=1e-7)


def test_per_frame_random_brightness_raises_flicker_and_energy() -> None:
    gt = _moving()
    gen = torch.Generator().manual_seed(0)
    gains = 1 + 0.2 * (torch.rand(gt.shape[0], 1, 1, 1, generator=gen) - 0.5)
    jittered = (gt * gains).clamp(0, 1)
    clean, noisy = temporal_flicker(gt, gt), temporal_flicker(jittered, gt)
    assert noisy.flicker > 0.01 > clean.flicker
    assert noisy.energy_ratio > 1.5
    # more jitter, more flicker
    wild = (gt * (1 + 2 * (gains - 1))).clamp(0, 1)
    assert temporal_flicker(wild, gt).flicker > noisy.flicker


def test_the_mask_ignores_changes_outside_the_object_and_closed_pairs_the_ends() -> None:
    gt = _moving(t=4)
    relit = gt.clone()
    relit[1, :, :, :8] += 0.5  # flicker in the left half only
    mask = torch.zeros(4, 16, 16)
    mask[:, :, 8:] = 1.0
    assert temporal_flicker(relit, gt, mask).flicker == pytest.approx(0.0, abs=1e-12)
    assert temporal_flicker(relit, gt).flicker > 0.05
    loop = temporal_flicker(gt, gt, closed=True)
    assert len(loop.per_pair) == 4 and loop.masked_fraction == 1.0


def test_bad_shapes_and_short_sequences_are_refused() -> None:
    gt = _moving(t=3)
    with pytest.raises(ShapeError):
        temporal_flicker(gt[:, :2], gt[:, :2])
    with pytest.raises(ShapeError):
        temporal_flicker(gt, gt[:2])
    with pytest.raises(ShapeError):
        temporal_flicker(gt, gt, torch.ones(3, 8, 8))
    with pytest.raises(ConfigError, match="at least 2"):
        temporal_flicker(gt[:1], gt[:1])
    with pytest.raises(ConfigError, match="no pixel"):
        temporal_flicker(gt, gt, torch.zeros(3, 16, 16))
