import importlib.util
import json
import subprocess
import sys
import textwrap

import pytest
import torch

from gaffer_diffusion.errors import MetricUnavailableError, ShapeError
from gaffer_diffusion.metrics import (
    channel_align,
    evaluate_images,
    load_perceptual,
    psnr,
    ssim,
)

HAS_STLPIPS = importlib.util.find_spec("stlpips_pytorch") is not None


def _pair(seed: int = 0, b: int = 2):
    g = torch.Generator().manual_seed(seed)
    gt = torch.rand(b, 3, 32, 32, generator=g)
    pred = (gt + 0.05 * torch.randn(gt.shape, generator=g)).clamp(0, 1)
    return pred, gt


def test_psnr_per_image_matches_definition() -> None:
    pred, gt = _pair()
    mse = ((pred - gt) ** 2).mean(dim=(1, 2, 3))
    torch.testing.assert_close(psnr(pred, gt), 10 * torch.log10(1 / mse))
    assert torch.isinf(psnr(gt, gt)).all()


def test_ssim_identity_and_order() -> None:
    pred, gt = _pair()
    s = ssim(pred, gt)
    assert s.shape == (2,)
    torch.testing.assert_close(ssim(gt, gt), torch.ones(2))
    assert (s < 1).all()


def test_channel_align_matches_means_over_image_and_mask() -> None:
    pred, gt = _pair()
    pred = pred * torch.tensor([0.5, 0.8, 0.6]).view(1, 3, 1, 1)
    aligned = channel_align(pred, gt)
    torch.testing.assert_close(aligned.mean(dim=(2, 3)), gt.mean(dim=(2, 3)), atol=2e-3, rtol=0)
    mask = torch.zeros(2, 1, 32, 32)
    mask[..., 8:24, 8:24] = 1
    aligned_m = channel_align(pred, gt, mask)
    inside = lambda x: x[..., 8:24, 8:24].mean(dim=(2, 3))  # noqa: E731
    torch.testing.assert_close(inside(aligned_m), inside(gt), atol=2e-3, rtol=0)
    # a global colour cast is removed exactly
    torch.testing.assert_close(channel_align(gt * 0.5, gt), gt, atol=1e-6, rtol=0)
    with pytest.raises(ShapeError, match="`mask`"):
        channel_align(pred, gt, mask[:, :, :16])


def test_report_labels_variants_and_means() -> None:
    pred, gt = _pair(b=3)
    mask = torch.ones(3, 1, 32, 32)
    report = evaluate_images(pred * 0.7, gt, mask=mask, names=["a", "b", "c"], perceptual=None)
    assert [i.name for i in report.items] == ["a", "b", "c"]
    assert (
        report.perceptual_name is None and report.perceptual_unavailable_reason == "not requested"
    )
    assert report.mean_aligned_image.psnr > report.mean_raw.psnr
    assert report.mean_raw.psnr == pytest.approx(sum(i.raw.psnr for i in report.items) / 3)
    md = report.to_markdown()
    assert "aligned (whole image)" in md and "aligned (mask means)" in md and "n/a" in md
    data = json.loads(report.to_json())
    assert data["items"][0]["aligned_mask"]["psnr"] == pytest.approx(
        report.items[0].aligned_mask.psnr
    )


def test_shape_mismatch_raises() -> None:
    pred, gt = _pair()
    with pytest.raises(ShapeError, match="`pred`"):
        psnr(pred[:, :, :16], gt)


def test_missing_lpips_backbone_says_why(tmp_path) -> None:
    with pytest.raises(MetricUnavailableError, match="alexnet-owt"):
        load_perceptual(tmp_path / "alexnet.pth")


@pytest.mark.skipif(not HAS_STLPIPS, reason="stlpips-pytorch not installed")
def test_stlpips_loads_offline_and_is_labelled() -> None:
    metric = load_perceptual()
    assert metric.name == "stlpips-alex"
    pred, gt = _pair()
    d = metric(pred, gt)
    assert d.shape == (2,) and (d > 0).all()
    torch.testing.assert_close(metric(gt, gt), torch.zeros(2))
    report = evaluate_images(pred, gt)
    assert report.perceptual_name == "stlpips-alex"
    assert "not standard LPIPS" in report.to_markdown()


@pytest.mark.slow
@pytest.mark.skipif(not HAS_STLPIPS, reason="stlpips-pytorch not installed")
def test_stlpips_matches_the_original_implementation(tmp_path) -> None:
    """Reference twin: the wheel's own code, run in a subprocess with stand-ins for torchvision,
    IPython and torchsummary (imported but unused by the shift-tolerant AlexNet path)."""
    stubs = tmp_path / "stubs"
    for name, body in {
        "torchvision/__init__.py": "from . import models\n",
        "torchvision/models.py": "",
        "IPython/__init__.py": "def embed(*a, **k):\n    pass\n",
        "torchsummary/__init__.py": "def summary(*a, **k):\n    pass\n",
    }.items():
        (stubs / name).parent.mkdir(parents=True, exist_ok=True)
        (stubs / name).write_text(body)
    pred, gt = _pair(seed=3, b=3)
    gt[2] = torch.rand(3, 32, 32)
    torch.save({"pred": pred, "gt": gt}, tmp_path / "in.pt")
    script = textwrap.dedent(
        f"""
        import sys, json, torch
        sys.path.insert(0, {str(stubs)!r})
        from stlpips_pytorch import stlpips
        m = stlpips.LPIPS(net="alex", variant="shift_tolerant", verbose=False)
        d = torch.load({str(tmp_path / "in.pt")!r})
        with torch.no_grad():
            print(json.dumps(m(d["pred"] * 2 - 1, d["gt"] * 2 - 1).flatten().tolist()))
        """
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    ref = torch.tensor(json.loads(out.stdout.strip().splitlines()[-1]))
    torch.testing.assert_close(load_perceptual()(pred, gt), ref, rtol=1e-5, atol=1e-6)
