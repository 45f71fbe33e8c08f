"""Object-centred framing of the training views: the same boxes as gaffer-diffusion's crops, exact
round trips, white outside the frame, gradients through the crop, and the model's framing by default."""

import numpy as np
import pytest
import torch

from gaffer_diffusion import PAPER_SAMPLING, RelightPipeline, pretrained
from gaffer_diffusion.preprocess import crop_square, object_square
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf.configs import DiffusionSamplingConfig
from gaffer_nerf.errors import ConfigError
from gaffer_nerf.guidance import DiffusionGuide
from gaffer_nerf.guidance.framing import frame_views


def _alpha(h: int, w: int, boxes: list[tuple[int, int, int, int]]) -> torch.Tensor:
    a = torch.zeros(len(boxes), h, w)
    for i, (y0, y1, x0, x1) in enumerate(boxes):
        a[i, y0:y1, x0:x1] = 1.0
    return a


def test_boxes_are_gaffer_diffusions_object_square() -> None:
    alpha = _alpha(48, 64, [(10, 30, 5, 25), (0, 48, 30, 40), (20, 22, 60, 64)])
    framing = frame_views(alpha, 0.75)
    for i in range(3):
        assert framing.boxes[i] == object_square(alpha[i].numpy(), 0.75)
    assert framing.image_size == (48, 64)


def test_a_view_without_object_is_shown_whole() -> None:
    framing = frame_views(_alpha(40, 60, [(0, 0, 0, 0)]), 0.75)
    assert framing.boxes == ((-10, 0, 60),)


def test_crop_matches_crop_square_with_white_fill() -> None:
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(2, 3, 32, 40, generator=gen)
    # the second object touches the border: its square reaches past the frame
    framing = frame_views(_alpha(32, 40, [(8, 20, 10, 22), (0, 12, 30, 40)]), 0.5)
    for i in range(2):
        side = framing.boxes[i][2]
        crop = framing.crop(images[i : i + 1], [i], side)[0]
        ref = crop_square(images[i].permute(1, 2, 0).numpy(), framing.boxes[i], fill=1.0)
        np.testing.assert_allclose(crop.permute(1, 2, 0).numpy(), ref, atol=1e-6)
    assert float(framing.crop(images[1:], [1], framing.boxes[1][2])[0, :, :2].min()) == 1.0


def test_paste_inverts_crop_at_the_box_size_and_keeps_the_rest() -> None:
    gen = torch.Generator().manual_seed(1)
    images = torch.rand(1, 3, 32, 32, generator=gen)
    framing = frame_views(_alpha(32, 32, [(4, 16, 6, 18)]), 0.75)
    top, left, side = framing.boxes[0]
    crop = framing.crop(images, [0], side)
    background = torch.zeros_like(images)
    pasted = framing.paste(crop, [0], background)
    torch.testing.assert_close(pasted[..., top : top + side, left : left + side], crop)
    inside = torch.zeros(32, 32, dtype=torch.bool)
    inside[top : top + side, left : left + side] = True
    assert float(pasted[..., ~inside].abs().max()) == 0.0


def test_crop_carries_gradients_to_the_box_only() -> None:
    images = torch.rand(1, 3, 32, 32, requires_grad=True)
    framing = frame_views(_alpha(32, 32, [(10, 20, 10, 20)]), 0.75)
    framing.crop(images, [0], 64).sum().backward()
    grad = images.grad
    assert grad is not None
    top, left, side = framing.boxes[0]
    assert float(grad[..., top : top + side, left : left + side].abs().min()) > 0.0
    assert float(grad[..., :top, :].abs().max()) == 0.0


def test_fraction_is_checked() -> None:
    for bad in (0.0, -0.5, 1.5, float("nan"), float("inf")):
        with pytest.raises(ConfigError, match="object_fraction"):
            DiffusionSamplingConfig(object_fraction=bad)
    with pytest.raises(ConfigError, match="object_fraction"):
        frame_views(torch.zeros(1, 8, 8), 0.0)


def test_gaffer_tiny_frames_views_and_the_paper_model_does_not() -> None:
    tiny = DiffusionSamplingConfig().resolved(pretrained.gaffer_tiny_sampling())
    assert tiny.crop_fraction == 0.75
    assert DiffusionSamplingConfig().resolved(PAPER_SAMPLING).crop_fraction is None
    whole = DiffusionSamplingConfig(object_fraction="whole").resolved(
        pretrained.gaffer_tiny_sampling()
    )
    assert whole.crop_fraction is None
    assert (
        DiffusionSamplingConfig(object_fraction=0.5).resolved(PAPER_SAMPLING).crop_fraction == 0.5
    )


def test_encoded_views_are_the_crops() -> None:
    """The guide encodes each view's crop (so a view that differs outside its box encodes the same)."""
    guide = DiffusionGuide(
        RelightPipeline(tiny_model()),
        DiffusionSamplingConfig(
            num_inference_steps=2, object_fraction=0.75, mirror_average=False, latent_mode="mode"
        ),
    )
    gen = torch.Generator().manual_seed(2)
    images = torch.rand(1, 3, 48, 48, generator=gen).repeat(2, 1, 1, 1)
    images[1, :, :, 40:] = 0.0  # outside the box of both views
    alpha = _alpha(48, 48, [(10, 30, 10, 30), (10, 30, 10, 30)])
    framing = guide.framing(alpha)
    assert framing is not None and framing.boxes[0][1] + framing.boxes[0][2] <= 40
    lighting = torch.rand(2, 3, 64, 64, generator=gen)
    from gaffer_diffusion import LightingMaps

    cond = guide.encode_views(images, LightingMaps(ldr=lighting, hdr=lighting), framing)
    assert cond.framing is framing
    lat = cond.encoded.image_latents
    torch.testing.assert_close(lat[0], lat[1], atol=1e-5, rtol=1e-5)
    relit = guide.relight_views(cond)
    assert relit.shape == (2, 3, 64, 64)
