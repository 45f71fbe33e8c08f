"""Object-mask metrics: `masked_psnr`, `masked_ssim`, `object_crop_box`, `closer_than` and the
object rows of `MetricsReport`."""

import dataclasses
import json
import math

import pytest
import torch

pytest.importorskip("torchmetrics")

from gaffer_diffusion.metrics import (
    OBJECT_CROP_MIN,
    PerceptualMetric,
    closer_than,
    combine_reports,
    evaluate_images,
    masked_psnr,
    masked_ssim,
    object_crop_box,
    psnr,
    ssim,
)

S = 48


def _scene(seed: int = 0, b: int = 2) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Ground truth, a prediction with noise inside the mask only, and a square mask."""
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(b, 3, S, S, generator=g)
    mask = torch.zeros(b, 1, S, S)
    mask[..., 16:32, 12:30] = 1.0
    pred = (gt + 0.05 * torch.randn(gt.shape, generator=g) * mask).clamp(0, 1)
    return pred, gt, mask


def test_masked_psnr_is_the_psnr_of_the_masked_pixels_only() -> None:
    pred, gt, mask = _scene()
    inside = mask[:, 0] > 0.5
    for i in range(pred.shape[0]):
        sel = inside[i]
        mse = ((pred[i][:, sel] - gt[i][:, sel]) ** 2).mean()
        assert float(masked_psnr(pred, gt, mask)[i]) == pytest.approx(
            float(10 * torch.log10(1 / mse)), abs=1e-4
        )
    # a background error changes the full-frame PSNR, not the object's
    spoiled = torch.where(mask > 0.5, pred, 1.0 - gt)
    torch.testing.assert_close(masked_psnr(spoiled, gt, mask), masked_psnr(pred, gt, mask))
    assert (psnr(spoiled, gt) < psnr(pred, gt) - 5).all()
    # an error inside the mask does change it
    worse = torch.where(mask > 0.5, (pred + 0.2).clamp(0, 1), pred)
    assert (masked_psnr(worse, gt, mask) < masked_psnr(pred, gt, mask)).all()
    # with a full mask it is the ordinary PSNR; exact match -> inf; empty mask -> nan
    torch.testing.assert_close(
        masked_psnr(pred, gt, torch.ones_like(mask)), psnr(pred, gt), atol=1e-4, rtol=0
    )
    assert torch.isinf(masked_psnr(gt, gt, mask)).all()
    assert torch.isnan(masked_psnr(pred, gt, torch.zeros_like(mask))).all()


def test_masked_ssim_ignores_the_background_away_from_the_object() -> None:
    pred, gt, mask = _scene()
    s = masked_ssim(pred, gt, mask)
    assert s.shape == (2,) and (s < 1).all() and (s > 0).all()
    torch.testing.assert_close(masked_ssim(gt, gt, mask), torch.ones(2), atol=1e-5, rtol=0)
    # change the background more than the 11-px window's half width away from the mask
    far = torch.ones_like(mask)
    far[..., 16 - 6 : 32 + 6, 12 - 6 : 30 + 6] = 0.0
    spoiled = torch.where(far > 0.5, 1.0 - gt, pred)
    torch.testing.assert_close(masked_ssim(spoiled, gt, mask), s, atol=1e-5, rtol=0)
    assert (ssim(spoiled, gt) < ssim(pred, gt) - 0.1).all()
    worse = torch.where(mask > 0.5, (pred + 0.2).clamp(0, 1), pred)
    assert (masked_ssim(worse, gt, mask) < s).all()


def test_object_crop_box() -> None:
    mask = torch.zeros(1, 20, 30)
    mask[0, 3:9, 10:25] = 1.0
    mask[0, 12, 2] = 0.4  # below the 0.5 threshold: not the object
    assert object_crop_box(mask) == (3, 10, 9, 25)
    mask[0, 15, 28] = 0.9
    assert object_crop_box(mask) == (3, 10, 16, 29)
    assert object_crop_box(torch.zeros(1, 20, 30)) == (0, 0, 20, 30)  # no object: whole image


def test_object_scores_present_iff_a_mask_is_passed() -> None:
    pred, gt, mask = _scene(b=3)
    unmasked = evaluate_images(pred, gt, perceptual=None)
    assert unmasked.mean_object_raw is None and unmasked.mean_object_aligned is None
    assert all(i.object_raw is None and i.object_aligned is None for i in unmasked.items)
    assert "object mask" not in unmasked.to_markdown()
    masked = evaluate_images(pred * 0.8, gt, mask=mask, perceptual=None)
    assert masked.mean_object_raw is not None and masked.mean_object_aligned is not None
    for i, item in enumerate(masked.items):
        assert item.object_raw is not None and item.object_aligned is not None
        assert item.object_raw.psnr == pytest.approx(
            float(masked_psnr(pred[i : i + 1] * 0.8, gt[i : i + 1], mask[i : i + 1])[0]), abs=1e-4
        )
        assert item.object_raw.perceptual is None  # none requested
    assert masked.mean_object_raw.psnr == pytest.approx(
        sum(i.object_raw.psnr for i in masked.items) / 3  # type: ignore[union-attr]
    )
    # alignment over the mask removes the 0.8 cast where it is scored
    assert masked.mean_object_aligned.psnr > masked.mean_object_raw.psnr
    doc = json.loads(masked.to_json())
    assert doc["mean_object_raw"]["psnr"] == pytest.approx(masked.mean_object_raw.psnr)
    assert doc["items"][0]["object_aligned"]["ssim"] == pytest.approx(
        masked.items[0].object_aligned.ssim  # type: ignore[union-attr]
    )


def test_markdown_lists_object_rows_before_full_frame() -> None:
    pred, gt, mask = _scene()
    md = evaluate_images(pred, gt, mask=mask, perceptual=None).to_markdown()
    order = [
        "object mask, raw",
        "object mask, aligned",
        "full frame, raw",
        "full frame, aligned (whole image)",
        "full frame, aligned (mask means)",
    ]
    positions = [md.index(label) for label in order]
    assert positions == sorted(positions)


def test_combine_reports_keeps_object_means() -> None:
    pred, gt, mask = _scene(b=4)
    whole = evaluate_images(pred, gt, mask=mask, perceptual=None)
    parts = [
        evaluate_images(pred[:1], gt[:1], mask=mask[:1], perceptual=None),
        evaluate_images(pred[1:], gt[1:], mask=mask[1:], perceptual=None),
    ]
    merged = combine_reports(parts)
    assert merged.mean_object_raw is not None and merged.mean_object_aligned is not None
    assert whole.mean_object_raw is not None and whole.mean_object_aligned is not None
    assert merged.mean_object_raw.psnr == pytest.approx(whole.mean_object_raw.psnr, abs=1e-5)
    assert merged.mean_object_raw.ssim == pytest.approx(whole.mean_object_raw.ssim, abs=1e-5)
    assert merged.mean_object_aligned.psnr == pytest.approx(
        whole.mean_object_aligned.psnr, abs=1e-5
    )
    unmasked = combine_reports([evaluate_images(pred, gt, perceptual=None)])
    assert unmasked.mean_object_raw is None and unmasked.mean_object_aligned is None


def test_closer_than_counts_object_psnr_wins() -> None:
    pred, gt, mask = _scene(b=4)
    names = ["a", "b", "c", "d"]
    # the baseline is worse on items 0 and 2, better on 1 and 3
    offset = torch.tensor([0.3, -0.3, 0.3, -0.3]).view(4, 1, 1, 1)
    base_pred = torch.where(offset > 0, (gt + 0.2).clamp(0, 1), pred)
    cand_pred = torch.where(offset > 0, pred, (gt + 0.2).clamp(0, 1))
    report = evaluate_images(cand_pred, gt, mask=mask, names=names, perceptual=None)
    baseline = evaluate_images(base_pred, gt, mask=mask, names=names, perceptual=None)
    assert closer_than(report, baseline) == pytest.approx(0.5)
    assert closer_than(baseline, report) == pytest.approx(0.5)
    better = evaluate_images(pred, gt, mask=mask, names=names, perceptual=None)
    assert closer_than(better, baseline) == pytest.approx(0.5)  # items 1, 3 tie: not wins
    last_only = torch.tensor([1.0, 1.0, 1.0, 0.0]).view(4, 1, 1, 1)
    worse_but_last = torch.where(last_only > 0, (gt + 0.2).clamp(0, 1), pred)
    baseline3 = evaluate_images(worse_but_last, gt, mask=mask, names=names, perceptual=None)
    assert closer_than(better, baseline3) == pytest.approx(0.75)
    assert closer_than(report, report) == 0.0  # ties are not wins
    # no object scores, different items or different lengths: None
    plain = evaluate_images(cand_pred, gt, names=names, perceptual=None)
    assert closer_than(plain, baseline) is None
    renamed = evaluate_images(base_pred, gt, mask=mask, names=list("wxyz"), perceptual=None)
    assert closer_than(report, renamed) is None
    short = evaluate_images(base_pred[:2], gt[:2], mask=mask[:2], names=names[:2], perceptual=None)
    assert closer_than(report, short) is None
    empty = dataclasses.replace(report, items=())
    assert closer_than(empty, dataclasses.replace(baseline, items=())) is None


class _RecordingDistance(torch.nn.Module):
    """A stand-in perceptual network: mean absolute difference, recording the input sizes."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = torch.nn.Parameter(torch.ones(()))
        self.sizes: list[tuple[int, int]] = []

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        self.sizes.append((int(a.shape[2]), int(a.shape[3])))
        return self.scale * (a - b).abs().mean(dim=(1, 2, 3))


def test_object_perceptual_runs_on_the_object_box_resized_up() -> None:
    pred, gt, mask = _scene(b=1)
    net = _RecordingDistance()
    metric = PerceptualMetric(name="lpips-alex", source="test", network=net)
    report = evaluate_images(pred, gt, mask=mask, perceptual=metric)
    item = report.items[0]
    assert item.object_raw is not None and item.object_raw.perceptual is not None
    # full frame for raw / aligned image / aligned mask, then the 16x18 box resized to >= 64 px
    side = max(OBJECT_CROP_MIN, 16, 18)
    assert net.sizes.count((S, S)) == 3 and net.sizes.count((side, side)) == 2
    assert math.isfinite(item.object_raw.perceptual) and item.object_raw.perceptual > 0
    # the background does not reach the object's perceptual score
    spoiled = torch.where(mask > 0.5, pred, 1.0 - gt)
    again = evaluate_images(spoiled, gt, mask=mask, perceptual=metric).items[0]
    assert again.object_raw is not None and again.object_raw.perceptual is not None
    assert again.object_raw.perceptual == pytest.approx(item.object_raw.perceptual, abs=1e-6)
    assert again.raw.perceptual is not None and item.raw.perceptual is not None
    assert again.raw.perceptual > item.raw.perceptual
