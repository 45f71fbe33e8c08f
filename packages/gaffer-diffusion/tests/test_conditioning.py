import pytest
import torch
import torch.nn.functional as F

from gaffer_diffusion import (
    InputValueError,
    LightingMaps,
    RelightingConditions,
    ShapeError,
    clip_preprocess,
    encode_conditions,
)
from gaffer_diffusion.configs import CLIP_MEAN, CLIP_STD
from gaffer_diffusion.testing import random_conditions, tiny_model


@pytest.fixture(scope="module")
def model():
    return tiny_model()


def test_encode_is_one_batched_vae_call_in_order_and_unscaled(model, monkeypatch) -> None:
    cond = random_conditions(2)
    calls = []
    original = model.vae.encode

    def spy(x, *args, **kwargs):
        calls.append(x.detach().clone())
        return original(x, *args, **kwargs)

    monkeypatch.setattr(model.vae, "encode", spy)
    enc = encode_conditions(model, cond)
    assert len(calls) == 1 and calls[0].shape == (6, 3, 64, 64)
    # [-1, 1] inputs, in the order image, HDR, LDR
    torch.testing.assert_close(calls[0][:2], cond.image * 2 - 1)
    torch.testing.assert_close(calls[0][2:4], cond.lighting.hdr * 2 - 1)
    torch.testing.assert_close(calls[0][4:], cond.lighting.ldr * 2 - 1)
    monkeypatch.undo()
    with torch.no_grad():
        ref = model.vae.encode(cond.lighting.ldr * 2 - 1).latent_dist.mode()
    # raw posterior mode: NOT multiplied by the scaling factor
    torch.testing.assert_close(enc.ldr_latents, ref, rtol=1e-5, atol=1e-5)
    assert enc.image_latents.shape == (2, 4, 8, 8)
    assert enc.clip_embeds.shape == (2, 1, model.config.unet.cross_attention_dim)
    cat = enc.concat_latents()
    assert torch.equal(cat[:, 0:4], enc.image_latents)
    assert torch.equal(cat[:, 4:8], enc.hdr_latents)
    assert torch.equal(cat[:, 8:12], enc.ldr_latents)


def test_clip_preprocess_matches_the_authors_recipe() -> None:
    x = torch.rand(2, 3, 64, 64) * 2 - 1
    out = clip_preprocess(x, 224)
    ref = F.interpolate(x, (224, 224), mode="bicubic", align_corners=True)
    ref = ((ref + 1) / 2 - torch.tensor(CLIP_MEAN).view(1, 3, 1, 1)) / torch.tensor(CLIP_STD).view(
        1, 3, 1, 1
    )
    torch.testing.assert_close(out, ref)
    assert out.shape == (2, 3, 224, 224)


def test_clip_embedding_is_the_projected_image_embedding(model) -> None:
    cond = random_conditions(1)
    enc = encode_conditions(model, cond)
    pixels = clip_preprocess(cond.image * 2 - 1, model.config.image_encoder.image_size)
    with torch.no_grad():
        ref = model.image_encoder(pixel_values=pixels).image_embeds
    torch.testing.assert_close(enc.clip_embeds[:, 0], ref)


def test_posterior_sample_mode_is_seeded_and_differs_from_mode(model) -> None:
    cond = random_conditions(1)
    mode = encode_conditions(model, cond)
    a = encode_conditions(
        model, cond, latent_mode="sample", generator=torch.Generator().manual_seed(1)
    )
    b = encode_conditions(
        model, cond, latent_mode="sample", generator=torch.Generator().manual_seed(1)
    )
    assert torch.equal(a.hdr_latents, b.hdr_latents)
    assert not torch.equal(a.hdr_latents, mode.hdr_latents)
    assert torch.equal(encode_conditions(model, cond).image_latents, mode.image_latents)


def test_encoded_repeat_and_select() -> None:
    enc = encode_conditions(tiny_model(), random_conditions(2))
    rep = enc.repeat_interleave(3)
    assert rep.batch_size == 6
    assert torch.equal(rep.image_latents[2], enc.image_latents[0])
    assert torch.equal(rep.clip_embeds[3], enc.clip_embeds[1])
    assert torch.equal(rep.select([3]).hdr_latents[0], enc.hdr_latents[1])


def test_condition_validation_errors() -> None:
    x = torch.rand(1, 3, 64, 64)
    with pytest.raises(ShapeError, match="`image`") as info:
        RelightingConditions(image=x.permute(0, 2, 3, 1), lighting=LightingMaps(ldr=x, hdr=x))
    assert info.value.actual == "(1, 64, 64, 3)"
    with pytest.raises(ShapeError, match="`hdr`"):
        LightingMaps(ldr=x, hdr=x[:, :, :32])
    with pytest.raises(ShapeError, match=r"lighting\.ldr"):
        RelightingConditions(
            image=x, lighting=LightingMaps(ldr=x[:, :, :32, :32], hdr=x[:, :, :32, :32])
        )
    nan = x.clone()
    nan[0, 0, 0, 0] = float("nan")
    with pytest.raises(InputValueError, match="NaN"):
        LightingMaps(ldr=nan, hdr=x)
    with pytest.raises(InputValueError, match=r"\[0, 1\]"):
        RelightingConditions(image=x * 255, lighting=LightingMaps(ldr=x, hdr=x))
    # tiny overshoot from resampling is clamped, not rejected
    maps = LightingMaps(ldr=x + 5e-4, hdr=x)
    assert float(maps.ldr.max()) <= 1.0


def test_wrong_resolution_raises(model) -> None:
    with pytest.raises(ShapeError, match="resolution"):
        encode_conditions(model, random_conditions(1, resolution=32))


def test_lighting_uses_the_filter_the_model_was_trained_with() -> None:
    """gaffer-envmap's default rotation filter became the power-exact "conservative" one;
    gaffer-tiny was trained on "area" maps, so every sampling path must keep asking for "area"
    (`LIGHTING_FILTER`) rather than follow the library default. A sub-pixel sun tells the two apart."""
    import numpy as np

    from gaffer_diffusion.conditioning import LIGHTING_FILTER, lighting_from_envmap
    from gaffer_envmap import encode_lighting, orbit_w2c_blender

    env = np.full((64, 128, 3), 0.05, np.float32)
    env[20, 37] = 400.0  # a one-texel sun
    pose = orbit_w2c_blender(23.0, 11.0, 2.0)
    maps = lighting_from_envmap(env, pose, size=32, compat="default")
    trained = encode_lighting(env, pose, size=32, filter=LIGHTING_FILTER)
    library_default = encode_lighting(env, pose, size=32)
    assert LIGHTING_FILTER == "area"
    assert torch.equal(maps.hdr, trained.hdr.float()) and torch.equal(maps.ldr, trained.ldr.float())
    assert float((maps.hdr - library_default.hdr.float()).abs().max()) > 1e-3
