import pytest
import torch
from diffusers import DDIMScheduler

from gaffer_diffusion import (
    SCHEDULERS,
    ConfigError,
    NonFiniteOutputError,
    RelightPipeline,
    RuntimeConfig,
    SamplingConfig,
    make_scheduler,
)
from gaffer_diffusion.testing import random_conditions, tiny_model

FAST = SamplingConfig(num_inference_steps=3)


@pytest.fixture(scope="module")
def pipe() -> RelightPipeline:
    return RelightPipeline(tiny_model())


def test_smoke_shapes_and_range(pipe) -> None:
    out = pipe(random_conditions(2), FAST, seeds=[0, 1])
    assert out.images.shape == (2, 3, 64, 64) and out.images.dtype == torch.float32
    assert out.latents.shape == (2, 4, 8, 8)
    assert 0.0 <= float(out.images.min()) and float(out.images.max()) <= 1.0
    assert out.retried_in_fp32 == ()


def test_ddim_50_leading_timesteps() -> None:
    s = make_scheduler("ddim")
    s.set_timesteps(50)
    assert s.timesteps.tolist() == list(range(981, 0, -20))
    assert isinstance(s, DDIMScheduler)


def test_unet_inputs_channel_order_and_unconditional_branch(pipe, monkeypatch) -> None:
    cond = random_conditions(2)
    enc = pipe.encode(cond)
    seen = []
    unet = pipe._unet

    def spy(sample, t, encoder_hidden_states):
        seen.append((sample.clone(), encoder_hidden_states.clone()))
        return unet(sample, t, encoder_hidden_states=encoder_hidden_states)

    monkeypatch.setattr(pipe, "_unet", spy)
    noise = pipe.initial_noise(2, seeds=[0, 1])
    pipe.sample(enc, SamplingConfig(num_inference_steps=2), latents=noise)
    x, ctx = seen[0]
    assert x.shape == (4, 16, 8, 8) and ctx.shape == (4, 1, 32)
    torch.testing.assert_close(x[:2, :4], noise)  # z_T (DDIM init sigma 1, identity scaling)
    assert torch.equal(x[:2, 4:8], enc.image_latents)
    assert torch.equal(x[:2, 8:12], enc.hdr_latents)
    assert torch.equal(x[:2, 12:16], enc.ldr_latents)
    assert torch.equal(ctx[:2], enc.clip_embeds)
    # unconditional half: same z_t, zero conditioning latents AND zero CLIP embedding
    assert torch.equal(x[2:, :4], x[:2, :4])
    assert torch.count_nonzero(x[2:, 4:]) == 0 and torch.count_nonzero(ctx[2:]) == 0
    seen.clear()
    pipe.sample(enc, SamplingConfig(num_inference_steps=2, guidance_scale=1.0), latents=noise)
    assert seen[0][0].shape[0] == 2  # guidance 1: no unconditional pass


def _reference_ddim(model, enc, noise, steps, scale):
    """Plain re-statement of official implementation §2 with diffusers' DDIMScheduler."""
    sched = DDIMScheduler(
        num_train_timesteps=1000,
        beta_start=0.00085,
        beta_end=0.012,
        beta_schedule="scaled_linear",
        steps_offset=1,
        clip_sample=False,
        set_alpha_to_one=False,
    )
    sched.set_timesteps(steps)
    z = noise.clone()
    c = torch.cat([enc.image_latents, enc.hdr_latents, enc.ldr_latents], 1)
    with torch.no_grad():
        for t in sched.timesteps:
            e_c = model.unet(torch.cat([z, c], 1), t, encoder_hidden_states=enc.clip_embeds).sample
            e_u = model.unet(
                torch.cat([z, torch.zeros_like(c)], 1),
                t,
                encoder_hidden_states=torch.zeros_like(enc.clip_embeds),
            ).sample
            z = sched.step(e_u + scale * (e_c - e_u), t, z, eta=0.0).prev_sample
        img = model.vae.decode(z / 0.18215).sample
    return (img / 2 + 0.5).clamp(0, 1)


def test_matches_reference_ddim_cfg_loop(pipe) -> None:
    enc = pipe.encode(random_conditions(2, seed=4))
    noise = pipe.initial_noise(2, seeds=[3, 4])
    out = pipe.sample(enc, SamplingConfig(num_inference_steps=4, guidance_scale=3.0), latents=noise)
    ref = _reference_ddim(pipe.model, enc, noise, 4, 3.0)
    torch.testing.assert_close(out.images, ref, rtol=1e-4, atol=1e-4)


def test_seeds_are_per_item_and_batch_invariant(pipe) -> None:
    cond = random_conditions(2)
    both = pipe(cond, FAST, seeds=[5, 6]).images
    enc = pipe.encode(cond)
    one = pipe.sample(enc.select([1]), FAST, seeds=[6]).images
    torch.testing.assert_close(both[1:], one, rtol=1e-4, atol=1e-4)
    again = pipe(cond, FAST, seeds=[5, 6]).images
    assert torch.equal(both, again)
    gen = pipe(cond, FAST, generator=[torch.Generator().manual_seed(s) for s in (5, 6)]).images
    assert torch.equal(both, gen)


def test_many_seeds_reuse_the_encoding(pipe, monkeypatch) -> None:
    enc = pipe.encode(random_conditions(1))
    calls = []
    monkeypatch.setattr(
        pipe.model.vae, "encode", lambda *a, **k: calls.append(1) or pytest.fail("re-encoded")
    )
    out = pipe.sample(enc, FAST, num_images_per_condition=3, seeds=[0, 1, 2])
    assert out.images.shape[0] == 3 and not calls
    assert not torch.equal(out.images[0], out.images[1])


@pytest.mark.parametrize("scheduler", SCHEDULERS)
def test_every_scheduler_runs_and_converges_to_ddim(pipe, scheduler) -> None:
    enc = pipe.encode(random_conditions(1))
    noise = pipe.initial_noise(1, seeds=[0])
    out = pipe.sample(
        enc, SamplingConfig(num_inference_steps=10, scheduler=scheduler), latents=noise
    )
    ddim = pipe.sample(enc, SamplingConfig(num_inference_steps=10), latents=noise)
    assert torch.isfinite(out.images).all()
    # same ODE, different solvers: close on a random tiny model, identical for DDIM
    assert float((out.images - ddim.images).abs().mean()) < 0.05


@pytest.mark.parametrize("dtype", ["float16", "bfloat16"])
def test_half_precision_runs_close_to_fp32(dtype) -> None:
    cond = random_conditions(1)
    ref = RelightPipeline(tiny_model())(cond, FAST, seeds=[0]).images
    out = RelightPipeline(tiny_model(), RuntimeConfig(dtype=dtype))(cond, FAST, seeds=[0])
    assert out.images.dtype == torch.float32 and torch.isfinite(out.images).all()
    assert float((out.images - ref).abs().max()) < 0.1


def test_eager_attention_matches_sdpa() -> None:
    cond = random_conditions(1)
    a = RelightPipeline(tiny_model())(cond, FAST, seeds=[0]).images
    b = RelightPipeline(tiny_model(), RuntimeConfig(attention="eager"))(
        cond, FAST, seeds=[0]
    ).images
    torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)


def test_compile_flag_wires_torch_compile() -> None:
    cond = random_conditions(1)
    a = RelightPipeline(tiny_model())(cond, FAST, seeds=[0]).images
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(compile=True, compile_backend="eager"))
    assert pipe._unet is not pipe.model.unet
    torch.testing.assert_close(pipe(cond, FAST, seeds=[0]).images, a, rtol=1e-5, atol=1e-5)


def test_bad_sampling_arguments_raise(pipe) -> None:
    with pytest.raises(ConfigError, match="`num_inference_steps`"):
        SamplingConfig(num_inference_steps=0)
    with pytest.raises(ConfigError, match="`guidance_scale`"):
        SamplingConfig(guidance_scale=float("nan"))
    with pytest.raises(ConfigError, match="`scheduler`"):
        SamplingConfig(scheduler="euler")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="`dtype`"):
        RuntimeConfig(dtype="float64")  # type: ignore[arg-type]
    enc = pipe.encode(random_conditions(2))
    with pytest.raises(ConfigError, match="`seeds`"):
        pipe.sample(enc, FAST, seeds=[0])
    with pytest.raises(ConfigError, match="not both"):
        pipe.sample(enc, FAST, seeds=[0, 1], generator=torch.Generator())
    with pytest.raises(ConfigError, match="`latents`"):
        pipe.sample(enc, FAST, latents=torch.zeros(2, 4, 4, 4))


@pytest.mark.parametrize(
    "sampling",
    [
        SamplingConfig(num_inference_steps=1),
        SamplingConfig(num_inference_steps=3, guidance_scale=0.0),
        SamplingConfig(num_inference_steps=3, guidance_scale=20.0),
        SamplingConfig(num_inference_steps=3, eta=1.0),
    ],
    ids=["1-step", "guidance-0", "guidance-20", "eta-1"],
)
def test_edge_settings_give_finite_images(pipe, sampling) -> None:
    out = pipe(random_conditions(2), sampling, seeds=[0, 1])
    assert torch.isfinite(out.images).all()


def _poison_fp16(pipe, monkeypatch):
    """Make the UNet overflow like fp16 does (Inf) when it runs in half precision."""
    unet = pipe._unet

    def overflowing(sample, t, encoder_hidden_states):
        out = unet(sample, t, encoder_hidden_states=encoder_hidden_states)
        if sample.dtype == torch.float16:
            out.sample[0] = float("inf")
        return out

    monkeypatch.setattr(pipe, "_unet", overflowing)


def test_nonfinite_output_raises_instead_of_nan_images(monkeypatch) -> None:
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype="float16"))
    _poison_fp16(pipe, monkeypatch)
    with pytest.raises(NonFiniteOutputError, match="float32") as info:
        pipe(random_conditions(2), FAST, seeds=[0, 1])
    assert info.value.indices == (0,)


def test_nonfinite_output_retries_affected_items_in_fp32(monkeypatch) -> None:
    cond = random_conditions(2)
    ref = RelightPipeline(tiny_model())(cond, FAST, seeds=[0, 1]).images
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype="float16"))
    _poison_fp16(pipe, monkeypatch)
    out = pipe(cond, SamplingConfig(num_inference_steps=3, nonfinite="retry_fp32"), seeds=[0, 1])
    assert out.retried_in_fp32 == (0,)
    assert torch.isfinite(out.images).all()
    # the retried item equals the float32 result up to the fp16 conditioning encoding
    assert float((out.images[0] - ref[0]).abs().max()) < 0.05


@pytest.mark.gpu
@pytest.mark.parametrize("dtype", ["float16", "bfloat16"])
def test_cuda_half_precision(dtype) -> None:
    cond = random_conditions(2)
    ref = RelightPipeline(tiny_model())(cond, FAST, seeds=[0, 1]).images
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(device="cuda", dtype=dtype))
    out = pipe(cond, FAST, seeds=[0, 1])
    assert out.images.device.type == "cuda"
    assert float((out.images.cpu() - ref).abs().max()) < 0.1


@pytest.mark.gpu
def test_cuda_compile_inductor() -> None:
    pipe = RelightPipeline(
        tiny_model(), RuntimeConfig(device="cuda", dtype="bfloat16", compile=True)
    )
    out = pipe(random_conditions(4), FAST, seeds=[0, 1, 2, 3])
    assert torch.isfinite(out.images).all()


def test_average_samples_is_the_mean_of_k_samples_per_item(pipe) -> None:
    import dataclasses

    cond = random_conditions(2, seed=4)
    enc = pipe.encode(cond)
    avg = dataclasses.replace(FAST, average_samples=3)
    out = pipe.sample(enc, avg, seeds=[5, 6])
    assert out.images.shape == (2, 3, 64, 64) and out.latents.shape[0] == 2
    # the same K noises, drawn in turn from each item's seed, sampled one by one and averaged
    h = pipe.model.config.latent_size
    for i, seed in enumerate((5, 6)):
        g = torch.Generator().manual_seed(seed)
        noise = torch.randn((3, 4, h, h), generator=g)
        each = pipe.sample(enc.select([i, i, i]), FAST, latents=noise).images
        torch.testing.assert_close(out.images[i], each.mean(0), rtol=1e-4, atol=1e-5)
    # batch invariant, and a different seed gives a different mean
    alone = pipe.sample(enc.select([1]), avg, seeds=[6]).images
    torch.testing.assert_close(alone[0], out.images[1], rtol=1e-4, atol=1e-5)
    assert not torch.allclose(pipe.sample(enc.select([1]), avg, seeds=[7]).images[0], alone[0])
    with pytest.raises(ConfigError, match="average_samples"):
        SamplingConfig(average_samples=0)
    with pytest.raises(ConfigError, match="eta"):
        SamplingConfig(average_samples=2, eta=0.5)
    with pytest.raises(ConfigError, match="latents"):
        pipe.sample(enc, avg, latents=torch.zeros(2, 4, h, h))


def test_mask_keeps_the_input_background_and_only_blends_edges(pipe) -> None:
    import dataclasses

    from gaffer_diffusion import ShapeError

    cond = random_conditions(2, seed=3)
    mask = torch.zeros(2, 1, 64, 64)
    mask[:, :, 16:48, 16:48] = 1.0
    mask[:, :, 16:48, 15] = 0.25  # a soft edge column
    full = pipe(cond, FAST, seeds=[1, 2, 3, 4], num_images_per_condition=2).images
    kept = pipe(
        dataclasses.replace(cond, mask=mask), FAST, seeds=[1, 2, 3, 4], num_images_per_condition=2
    ).images
    x = cond.image.repeat_interleave(2, dim=0)
    inside = mask.repeat_interleave(2, dim=0).expand(-1, 3, -1, -1) == 1.0
    outside = mask.repeat_interleave(2, dim=0).expand(-1, 3, -1, -1) == 0.0
    assert torch.equal(kept[inside], full[inside])  # the object: the model's pixels
    assert torch.equal(kept[outside], x[outside])  # the background: the input's
    torch.testing.assert_close(
        kept[:, :, 16:48, 15], x[:, :, 16:48, 15] + 0.25 * (full - x)[:, :, 16:48, 15]
    )
    with pytest.raises(ShapeError, match="mask"):
        dataclasses.replace(cond, mask=torch.ones(2, 1, 32, 32))
    with pytest.raises(ShapeError, match="mask"):
        dataclasses.replace(cond, mask=torch.ones(2, 3, 64, 64))


def test_mirror_average_is_the_mean_of_the_prediction_and_the_mirrored_one(pipe) -> None:
    import dataclasses

    from gaffer_diffusion.conditioning import LightingMaps
    from gaffer_envmap.augment import mirror_camera_x

    cond = random_conditions(2, seed=5)
    mask = (torch.rand(2, 1, 64, 64, generator=torch.Generator().manual_seed(0)) > 0.3).float()
    cond = dataclasses.replace(cond, mask=mask)
    both = pipe(cond, dataclasses.replace(FAST, mirror_average=True), seeds=[3, 4]).images
    plain = pipe(cond, FAST, seeds=[3, 4]).images
    mirrored = dataclasses.replace(
        cond,
        image=cond.image.flip(-1),
        lighting=LightingMaps(
            ldr=mirror_camera_x(cond.lighting.ldr), hdr=mirror_camera_x(cond.lighting.hdr)
        ),
        mask=mask.flip(-1),
    )
    back = pipe(mirrored, FAST, seeds=[3, 4]).images.flip(-1)
    torch.testing.assert_close(both, (plain + back) / 2, rtol=1e-4, atol=1e-5)
    assert not torch.allclose(both, plain, atol=1e-3)
    # batch invariant, and with several images per condition
    alone = pipe(
        dataclasses.replace(
            cond,
            image=cond.image[1:],
            lighting=LightingMaps(ldr=cond.lighting.ldr[1:], hdr=cond.lighting.hdr[1:]),
            mask=mask[1:],
        ),
        dataclasses.replace(FAST, mirror_average=True),
        seeds=[4],
    ).images
    torch.testing.assert_close(alone[0], both[1], rtol=1e-4, atol=1e-5)
    k2 = pipe(
        cond,
        dataclasses.replace(FAST, mirror_average=True),
        seeds=[3, 9, 4, 9],
        num_images_per_condition=2,
    ).images
    assert k2.shape == (4, 3, 64, 64)
    torch.testing.assert_close(k2[[0, 2]], both, rtol=1e-4, atol=1e-5)
