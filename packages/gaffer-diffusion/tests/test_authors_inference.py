"""The authors' inference: posterior-sampled conditioning latents, seeded per item,
and the fp16 autocast path (weights float32, UNet under `torch.autocast`)."""

import dataclasses

import pytest
import torch

from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig
from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions, encode_conditions
from gaffer_diffusion.errors import ConfigError, ShapeError
from gaffer_diffusion.testing import random_conditions, tiny_model

FAST = SamplingConfig(num_inference_steps=2, guidance_scale=3.0)
SAMPLE = dataclasses.replace(FAST, latent_mode="sample")


@pytest.fixture(scope="module")
def pipe() -> RelightPipeline:
    return RelightPipeline(tiny_model())


def _item(cond: RelightingConditions, i: int) -> RelightingConditions:
    return RelightingConditions(
        image=cond.image[i : i + 1],
        lighting=LightingMaps(ldr=cond.lighting.ldr[i : i + 1], hdr=cond.lighting.hdr[i : i + 1]),
    )


def test_sampled_latents_are_reproducible_per_item_and_differ_from_the_mode(pipe) -> None:
    cond = random_conditions(3, seed=4)
    a = pipe(cond, SAMPLE, seeds=[5, 6, 7]).images
    b = pipe(cond, SAMPLE, seeds=[5, 6, 7]).images
    assert torch.equal(a, b)
    mode = pipe(cond, FAST, seeds=[5, 6, 7]).images
    assert float((a - mode).abs().max()) > 1e-3
    # an item's result does not depend on the batch it landed in
    alone = pipe(_item(cond, 1), SAMPLE, seeds=[6]).images
    torch.testing.assert_close(alone[0], a[1], atol=1e-5, rtol=0)
    other_seed = pipe(_item(cond, 1), SAMPLE, seeds=[8]).images
    assert float((other_seed[0] - a[1]).abs().max()) > 1e-3


def test_posterior_noise_continues_the_items_noise_stream(pipe) -> None:
    """One generator per item, initial noise first, then image/HDR/LDR posterior noise (our reading
    of their order); so `mode` and `sample` with one seed start from the same z_T."""
    cond = random_conditions(2, seed=1)
    gens = pipe._posterior_generators(2, SAMPLE, 1, None, [3, 9])
    assert isinstance(gens, list) and len(gens) == 2
    ref = torch.Generator().manual_seed(9)
    z_t = pipe.initial_noise(1, seeds=[9])
    torch.testing.assert_close(torch.randn(z_t.shape, generator=ref), z_t)
    # after z_T: the item's posterior noise, image first
    expected_eps = torch.randn((1, 4, 8, 8), generator=ref)
    got_eps = torch.randn((1, 4, 8, 8), generator=gens[1])
    assert torch.equal(expected_eps, got_eps)
    enc = encode_conditions(pipe.model, cond, latent_mode="sample", generator=gens)
    post = pipe.model.vae.encode(torch.cat([cond.image, cond.lighting.hdr]) * 2 - 1).latent_dist
    assert not torch.allclose(enc.image_latents, post.mode()[:2])
    assert pipe._posterior_generators(2, FAST, 1, None, [3, 9]) is None


def test_encode_conditions_checks_the_generator_list(pipe) -> None:
    cond = random_conditions(2)
    with pytest.raises(ShapeError, match="one generator per item"):
        encode_conditions(pipe.model, cond, latent_mode="sample", generator=[torch.Generator()])


def test_autocast_keeps_float32_weights_and_runs_the_unet_in_low_precision() -> None:
    cond = random_conditions(2, seed=2)
    ref = RelightPipeline(tiny_model())(cond, FAST, seeds=[0, 1]).images
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype="bfloat16", autocast=True))
    assert next(pipe.model.unet.parameters()).dtype == torch.float32
    assert pipe.dtype == torch.float32
    seen: list[tuple[bool, torch.dtype]] = []
    hook = pipe.model.unet.conv_in.register_forward_hook(
        lambda _m, _i, out: seen.append((torch.is_autocast_enabled("cpu"), out.dtype))
    )
    try:
        out = pipe(cond, FAST, seeds=[0, 1]).images
    finally:
        hook.remove()
    assert seen and all(on and dt == torch.bfloat16 for on, dt in seen)
    assert out.dtype == torch.float32 and torch.isfinite(out).all()
    diff = float((out - ref).abs().max())
    assert 0 < diff < 0.1  # low precision changes the numbers, not the picture


def test_autocast_needs_a_low_precision_dtype() -> None:
    with pytest.raises(ConfigError, match="autocast"):
        RuntimeConfig(autocast=True)


@pytest.mark.gpu
def test_cuda_fp16_autocast_matches_float32() -> None:
    cond = random_conditions(2)
    ref = RelightPipeline(tiny_model())(cond, SAMPLE, seeds=[0, 1]).images
    pipe = RelightPipeline(
        tiny_model(), RuntimeConfig(device="cuda", dtype="float16", autocast=True)
    )
    out = pipe(cond, SAMPLE, seeds=[0, 1]).images
    assert out.device.type == "cuda" and next(pipe.model.unet.parameters()).dtype == torch.float32
    assert float((out.cpu() - ref).abs().max()) < 0.1


def test_cli_defaults_follow_the_compat_reading() -> None:
    from gaffer_diffusion.cli import _latent_mode, _parser, _runtime

    def parse(*extra: str):
        return _parser().parse_args(["relight", "x.png", "--out", "o.png", *extra])

    assert _latent_mode(parse("--compat", "neural-gaffer")) == "sample"
    assert _latent_mode(parse("--checkpoint", "ckpt")) == "sample"  # the authors' by default
    assert _latent_mode(parse()) == "mode"  # gaffer-tiny: unchanged
    assert _latent_mode(parse("--compat", "neural-gaffer", "--latent-mode", "mode")) == "mode"
    cuda = ("--device", "cuda", "--dtype", "float16")
    assert _runtime(parse("--compat", "neural-gaffer", *cuda)).autocast
    assert not _runtime(parse("--compat", "default", *cuda)).autocast
    assert not _runtime(parse("--compat", "neural-gaffer", "--dtype", "float16")).autocast  # CPU
    assert not _runtime(parse("--compat", "neural-gaffer", *cuda, "--no-autocast")).autocast
    with pytest.raises(ConfigError, match="--dtype float16"):
        _runtime(parse("--autocast"))


def test_cli_turntable_frames_are_the_authors_frames_in_order(tmp_path) -> None:
    """`relight --turntable N --compat neural-gaffer`: frame k is their frame k of N."""
    import numpy as np

    from gaffer_diffusion.cli import _envmap_lighting, _parser
    from gaffer_envmap import EnvironmentMap, orbit_w2c_blender, write_envmap
    from gaffer_envmap.testing import reference_neural_gaffer

    env = (np.random.default_rng(0).random((16, 32, 3)) ** 4 * 20).astype(np.float32)
    write_envmap(tmp_path / "sky.exr", EnvironmentMap(radiance_linear=env))
    light = ["--envmap", str(tmp_path / "sky.exr"), "--azimuth", "30", "--elevation", "10"]
    args = _parser().parse_args(
        [
            "relight",
            "x.png",
            "--out",
            "o.png",
            *light,
            "--compat",
            "neural-gaffer",
            "--turntable",
            "4",
        ]
    )
    maps = _envmap_lighting(args, tmp_path / "sky.exr", 32, 4)
    ldr = torch.round(maps.ldr * 255).to(torch.uint8).permute(0, 2, 3, 1).numpy()
    pose = orbit_w2c_blender(30, 10).matrix
    for k in range(4):
        ref, _ = reference_neural_gaffer(env, pose, 32, frame=k, num_frames=4)
        assert np.array_equal(ldr[k], ref), k
