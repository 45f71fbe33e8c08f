import dataclasses

import pytest
import torch

from gaffer_diffusion import (
    PRESETS,
    ConfigError,
    build_model,
    expand_conv_in,
    get_preset,
)
from gaffer_diffusion.models import build_unet, config_from_modules
from gaffer_diffusion.testing import tiny_model


def test_presets_build_and_validate() -> None:
    for name in PRESETS:
        cfg = get_preset(name)
        assert cfg.unet.in_channels == 16 + cfg.hint_channels
        assert cfg.hint_channels == (12 if cfg.hints else 0)
        assert cfg.latent_size * cfg.vae.downsampling_factor == cfg.resolution


def test_neural_gaffer_256_is_the_authors_shape() -> None:
    cfg = get_preset("neural-gaffer-256")
    assert cfg.resolution == 256 and cfg.latent_size == 32
    assert cfg.unet.block_out_channels == (320, 640, 1280, 1280)
    assert cfg.unet.layers_per_block == 2 and cfg.unet.attention_head_dim == 8
    assert cfg.unet.cross_attention_dim == 768 == cfg.image_encoder.projection_dim
    assert cfg.vae.block_out_channels == (128, 256, 512, 512)
    assert cfg.vae.scaling_factor == pytest.approx(0.18215)
    enc = cfg.image_encoder
    assert (enc.hidden_size, enc.num_hidden_layers, enc.patch_size, enc.image_size) == (
        1024,
        24,
        14,
        224,
    )
    s = cfg.scheduler
    assert (s.beta_start, s.beta_end, s.beta_schedule, s.steps_offset) == (
        0.00085,
        0.012,
        "scaled_linear",
        1,
    )


@pytest.mark.slow
def test_neural_gaffer_256_unet_parameter_count() -> None:
    # meta device: shapes only, no memory; 859.5M parameters (official implementation §1)
    with torch.device("meta"):
        unet = build_unet(get_preset("neural-gaffer-256").unet)
    n = sum(p.numel() for p in unet.parameters())
    assert 859.4e6 < n < 859.7e6
    assert unet.conv_in.weight.shape == (320, 16, 3, 3)


def test_unknown_preset_and_inconsistent_config_raise() -> None:
    with pytest.raises(ConfigError, match="`name`"):
        get_preset("sd-xl")  # type: ignore[arg-type]
    cfg = get_preset("tiny")
    with pytest.raises(ConfigError, match="in_channels"):
        dataclasses.replace(cfg, unet=dataclasses.replace(cfg.unet, in_channels=8))
    with pytest.raises(ConfigError, match="cross_attention_dim"):
        dataclasses.replace(cfg, unet=dataclasses.replace(cfg.unet, cross_attention_dim=16))
    with pytest.raises(ConfigError, match="sample_size"):
        dataclasses.replace(cfg, resolution=128)
    assert cfg.with_resolution(128).latent_size == 16


def test_build_is_deterministic_and_config_round_trips() -> None:
    a, b = tiny_model(seed=3), tiny_model(seed=3)
    for pa, pb in zip(a.unet.parameters(), b.unet.parameters(), strict=True):
        assert torch.equal(pa, pb)
    assert not torch.equal(a.unet.conv_in.weight, tiny_model(seed=4).unet.conv_in.weight)
    cfg = config_from_modules(a.unet, a.vae, a.image_encoder, None, name="tiny")
    assert cfg == a.config


def test_expand_conv_in_zero_inits_new_channels_and_preserves_output() -> None:
    cfg = get_preset("tiny")
    torch.manual_seed(0)
    unet = build_unet(dataclasses.replace(cfg.unet, in_channels=8)).eval()
    x = torch.randn(1, 8, 8, 8)
    ctx = torch.randn(1, 1, cfg.unet.cross_attention_dim)
    with torch.no_grad():
        before = unet(x, 10, encoder_hidden_states=ctx).sample
        old_w = unet.conv_in.weight.clone()
        old_b = unet.conv_in.bias.clone()
        expand_conv_in(unet, 16)
        after = unet(
            torch.cat([x, torch.randn(1, 8, 8, 8) * 0], 1), 10, encoder_hidden_states=ctx
        ).sample
    assert unet.conv_in.weight.shape == (32, 16, 3, 3)
    assert unet.config.in_channels == 16
    assert torch.equal(unet.conv_in.weight[:, :8], old_w)
    assert torch.count_nonzero(unet.conv_in.weight[:, 8:]) == 0
    assert torch.equal(unet.conv_in.bias, old_b)
    torch.testing.assert_close(after, before)
    with pytest.raises(ConfigError, match="`in_channels`"):
        expand_conv_in(unet, 4)


def test_model_to_dtype() -> None:
    m = build_model(get_preset("tiny")).to(dtype=torch.bfloat16)
    assert m.dtype == torch.bfloat16 and m.device.type == "cpu"
