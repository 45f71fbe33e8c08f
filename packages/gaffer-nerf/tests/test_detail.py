"""Stage-1 shading transfer: the model's change of light applied to the input views."""

import dataclasses
import inspect
import math

import jaxtyping
import pytest
import torch

from gaffer_diffusion import RelightPipeline
from gaffer_diffusion.detail_transfer import linear_to_srgb, srgb_to_linear
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf.configs import (
    DiffusionSamplingConfig,
    Stage1Config,
    Stage2Config,
    relight_preset,
)
from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.guidance import DiffusionGuide, unavailable_perceptual
from gaffer_nerf.relight import relight_field
from gaffer_nerf.relight.detail import transfer_shading


def _disc(v: int = 2, size: int = 32) -> tuple[torch.Tensor, torch.Tensor]:
    """A textured disc (checkerboard albedo) over white, and its alpha."""
    yy, xx = torch.meshgrid(torch.arange(size), torch.arange(size), indexing="ij")
    alpha = (((yy - size / 2 + 0.5) ** 2 + (xx - size / 2 + 0.5) ** 2) < (size / 3) ** 2).float()
    checker = 0.5 + 0.4 * ((yy // 2 + xx // 2) % 2).float()
    obj = torch.stack([checker, 0.9 * checker, 0.8 * checker])
    img = alpha * obj + (1 - alpha)
    return img.expand(v, 3, size, size).clone(), alpha.expand(v, size, size).clone()


def _relight_linear(img: torch.Tensor, alpha: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    lin = torch.from_numpy(srgb_to_linear(img.permute(0, 2, 3, 1).numpy()))
    out = torch.from_numpy(linear_to_srgb((lin * gain).numpy())).permute(0, 3, 1, 2)
    return alpha[:, None] * out + (1 - alpha[:, None])


@pytest.mark.parametrize("radius", [0, 1, 3])
def test_a_uniform_change_of_light_is_reproduced(radius: int) -> None:
    """Pixel by pixel exactly; averaged over a box, up to the ratio's regulariser (`EPS_LINEAR` on
    both sides makes the ratio of a uniform gain differ a little between dark and bright texels)."""
    img, alpha = _disc()
    gain = torch.tensor([1.2, 0.9, 0.5])  # a warmer light: one ratio per channel, none clipped
    relit = _relight_linear(img, alpha, gain)
    out = transfer_shading(img, relit, alpha, radius)
    inside = alpha > 0.5
    err = (out - relit).abs().permute(0, 2, 3, 1)[inside]
    assert float(err.max()) < (2e-3 if radius == 0 else 1e-2)
    assert torch.equal(out.permute(0, 2, 3, 1)[~inside], relit.permute(0, 2, 3, 1)[~inside])


def test_the_input_texture_survives_a_model_that_blurs_it() -> None:
    """The model's output blurs the checkerboard; the transfer keeps it and still takes the light."""
    img, alpha = _disc()
    gain = torch.tensor([0.5, 0.5, 0.5])
    relit = _relight_linear(img, alpha, gain)
    k = torch.ones(3, 1, 5, 5) / 25
    blurred = torch.nn.functional.conv2d(
        torch.nn.functional.pad(relit, (2, 2, 2, 2), mode="replicate"), k, groups=3
    )
    blurred = alpha[:, None] * blurred + (1 - alpha[:, None])
    out = transfer_shading(img, blurred, alpha, 3)
    inside = (alpha > 0.5)[:, None].expand_as(out)
    err_transfer = float((out - relit).abs()[inside].mean())
    err_model = float((blurred - relit).abs()[inside].mean())
    assert err_transfer < 0.5 * err_model
    # the level follows the model (darker), not the input
    assert float(out[inside].mean()) < float(img[inside].mean()) - 0.1


def test_a_view_without_object_keeps_the_relit_view() -> None:
    img, alpha = _disc(v=2)
    alpha[1] = 0.0
    relit = torch.rand_like(img)
    out = transfer_shading(img, relit, alpha, 2)
    assert torch.equal(out[1], relit[1])
    assert torch.isfinite(out).all()


def test_shapes_are_checked() -> None:
    """By the annotations where the type hook runs (tests), else by the function itself."""
    img, alpha = _disc()
    bad = (ShapeError, jaxtyping.TypeCheckError)
    with pytest.raises(bad, match="relit_srgb"):
        transfer_shading(img, img[:, :, :16], alpha, 1)
    with pytest.raises(bad, match="alpha"):
        transfer_shading(img, img, alpha[:1], 1)
    with pytest.raises(bad, match="inputs_srgb"):
        transfer_shading(img[:, :2], img[:, :2], alpha, 1)
    unchecked = inspect.unwrap(transfer_shading)
    with pytest.raises(ShapeError, match="relit_srgb"):
        unchecked(img, img[:, :, :16], alpha, 1)
    with pytest.raises(ShapeError, match="alpha"):
        unchecked(img, img, alpha[:1], 1)


@pytest.mark.parametrize("config_class", [Stage1Config, Stage2Config])
def test_config_refuses_bad_values(config_class) -> None:
    with pytest.raises((ConfigError, jaxtyping.TypeCheckError), match="target_detail"):
        config_class(target_detail="sharpen")
    with pytest.raises(ConfigError, match="transfer_radius_px"):
        config_class(transfer_radius_px=-1)


def test_relight_field_fits_the_transferred_targets(fitted, scene, monkeypatch) -> None:
    """With target_detail="transfer", Stage 1 fits the input views times the model's change of
    shading (not the model's views as they are); the oracle `stage1_targets` stay as given."""
    import gaffer_nerf.relight.run as run_mod

    seen: list[torch.Tensor] = []
    real_stage1 = run_mod.run_stage1

    def spy(field, cache, targets_rgb, config, **kw):
        seen.append(targets_rgb.clone())
        return real_stage1(field, cache, targets_rgb, config, **kw)

    monkeypatch.setattr(run_mod, "run_stage1", spy)
    cfg = relight_preset("tiny", "no-stage2")
    assert cfg.stage1 is not None
    diffusion = DiffusionSamplingConfig(object_fraction=0.75, num_inference_steps=2)
    guide = DiffusionGuide(RelightPipeline(tiny_model()), diffusion)
    assert scene.train.alpha is not None
    framing = guide.framing(scene.train.alpha)
    assert framing is not None
    crops = torch.rand(8, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    images = scene.train.rgb_srgb.permute(0, 3, 1, 2)
    pasted = framing.paste(crops, list(range(8)), images)
    flat = {
        "model": pasted.permute(0, 2, 3, 1).reshape(-1, 3),
        "transfer": transfer_shading(images, pasted, scene.train.alpha, 3)
        .permute(0, 2, 3, 1)
        .reshape(-1, 3),
    }
    assert not torch.allclose(flat["model"], flat["transfer"], atol=1e-3)
    for detail in ("model", "transfer"):
        c = dataclasses.replace(
            cfg,
            diffusion=diffusion,
            stage1=dataclasses.replace(
                cfg.stage1, iterations=5, target_detail=detail, transfer_radius_px=3
            ),
        )
        relight_field(
            fitted.field, scene.train, scene.env_target, guide, c,
            unavailable_perceptual("not requested"), relit_views=crops,
        )  # fmt: skip
        torch.testing.assert_close(seen[-1], flat[detail])
    oracle = images.clone()
    relight_field(
        fitted.field, scene.train, scene.env_target, guide, c,
        unavailable_perceptual("not requested"), stage1_targets=oracle,
    )  # fmt: skip
    torch.testing.assert_close(seen[-1], oracle.permute(0, 2, 3, 1).reshape(-1, 3))


def test_cli_flags_reach_stage1() -> None:
    from gaffer_nerf.cli import _parser, _relight_config

    base = ["relight", "f", "--data", "d", "--out", "o", "--target-lighting", "1"]
    args = _parser().parse_args(
        [*base, "--stage1-detail", "transfer", "--stage1-transfer-radius", "4"]
    )
    s1 = _relight_config(args).stage1
    assert (s1.target_detail, s1.transfer_radius_px) == ("transfer", 4)
    preset = relight_preset("tiny").stage1
    assert preset is not None
    s1 = _relight_config(_parser().parse_args([*base, "--preset", "tiny"])).stage1
    assert (s1.target_detail, s1.transfer_radius_px) == (
        preset.target_detail,
        preset.transfer_radius_px,
    )


def test_per_view_noise_is_the_tiny_presets_and_the_flag_overrides_it() -> None:
    """The tiny preset relights every view from its own noise (chosen on the 128 px validation
    objects of `benchmarks/bench_nerf_cli_defaults.py --validation`; the 64 px sweep's shared noise,
    `python benchmarks/nerf_sweep.py run noise`, is superseded); `--no-shared-noise` /
    `--shared-noise` override any preset."""
    from gaffer_nerf.cli import _parser, _relight_config

    base = ["relight", "f", "--data", "d", "--out", "o", "--target-lighting", "1"]

    def shared(*extra: str) -> bool:
        return _relight_config(_parser().parse_args([*base, *extra])).diffusion.shared_noise

    assert relight_preset("tiny").diffusion.shared_noise is False
    assert relight_preset("paper").diffusion.shared_noise is False
    assert shared("--preset", "tiny") is False
    assert shared("--preset", "tiny", "--shared-noise") is True
    assert shared("--preset", "paper") is False
    assert shared("--preset", "paper", "--shared-noise") is True


@pytest.mark.parametrize("detail", ["model", "transfer"])
def test_stage2_transfers_the_guidance_target_only_when_asked(
    fitted, scene, monkeypatch, detail: str
) -> None:
    """`Stage2Config.target_detail="transfer"`: every guidance step's target is the render times the
    model's change of shading, with the field's opacity cropped as the model sees the view."""
    import gaffer_nerf.relight.stage2 as stage2_mod

    calls: list[tuple[tuple[int, ...], float, float, int]] = []
    real_transfer = stage2_mod.transfer_shading

    def spy(inputs, relit, alpha, radius):
        calls.append((tuple(alpha.shape), float(alpha.min()), float(alpha.max()), radius))
        return real_transfer(inputs, relit, alpha, radius)

    monkeypatch.setattr(stage2_mod, "transfer_shading", spy)
    cfg = relight_preset("tiny", "no-stage1")
    assert cfg.stage2 is not None
    diffusion = DiffusionSamplingConfig(object_fraction=0.75, num_inference_steps=2)
    cfg = dataclasses.replace(
        cfg,
        diffusion=diffusion,
        stage2=dataclasses.replace(
            cfg.stage2, iterations=3, target_detail=detail, transfer_radius_px=5
        ),
    )
    guide = DiffusionGuide(RelightPipeline(tiny_model()), diffusion)
    res = relight_field(
        fitted.field, scene.train, scene.env_target, guide, cfg,
        unavailable_perceptual("not requested"),
    )  # fmt: skip
    assert res.report.stage2 is not None
    assert all(math.isfinite(x) for x in res.report.stage2.losses)
    if detail == "model":
        assert calls == []
    else:
        assert len(calls) == 3
        for shape, lo, hi, radius in calls:
            assert shape == (1, guide.resolution, guide.resolution) and radius == 5
            assert 0.0 <= lo and hi <= 1.0 and hi > 0.5  # the object is in the crop
