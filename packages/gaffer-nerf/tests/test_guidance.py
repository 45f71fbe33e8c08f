"""The diffusion prior for 3D: reference-twin loop, SDEdit targets, SDS gradients, perceptual fallback."""

import logging

import pytest
import torch

import gaffer_nerf.guidance.perceptual as perceptual_mod
from gaffer_diffusion import RelightPipeline, SamplingConfig, build_model
from gaffer_diffusion.errors import MetricUnavailableError
from gaffer_diffusion.testing import random_conditions, tiny_model
from gaffer_nerf.configs import DiffusionSamplingConfig, Stage2Config
from gaffer_nerf.guidance import (
    DiffusionGuide,
    PerceptualUnavailableWarning,
    load_perceptual_loss,
)


@pytest.fixture(scope="module")
def guide() -> DiffusionGuide:
    return DiffusionGuide(
        RelightPipeline(tiny_model()), DiffusionSamplingConfig(num_inference_steps=6, batch_size=2)
    )


def test_denoise_from_the_whole_schedule_equals_sampling_from_the_noised_latents(
    guide: DiffusionGuide,
) -> None:
    # one sampler: Stage 2's img2img runs `sample`'s loop; from t* = 1 over the whole schedule it
    # equals `sample` started from the input's latents noised to the schedule's first step
    pipe = guide.pipeline
    cond = random_conditions(2, 64, seed=1)
    enc = pipe.encode(cond)
    x = torch.rand(2, 3, 64, 64, generator=torch.Generator().manual_seed(2))
    noise = torch.randn(2, 4, 8, 8, generator=torch.Generator().manual_seed(0))
    sampling = SamplingConfig(num_inference_steps=6, guidance_scale=3.0)
    sched, ts = pipe.img2img_timesteps(1.0, sampling)
    assert ts.tolist() == sched.timesteps.tolist()  # t* = 1: every step
    z_t = pipe.add_noise(pipe.encode_images(x, enc), noise, ts[:1].repeat(2))
    ref = pipe.sample(enc, sampling, latents=z_t).images
    got = pipe.denoise_from(x, 1.0, enc, sampling, noise=noise)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    # and the guide's Stage 2 target is the pipeline's img2img with the guide's sampling
    g = torch.Generator().manual_seed(3)
    want = pipe.denoise_from(x, 0.4, enc, guide.sampling_config(), generator=g)
    g = torch.Generator().manual_seed(3)
    torch.testing.assert_close(guide.denoise_from(x, enc, 0.4, generator=g), want)


def test_relight_views_are_batch_invariant(guide: DiffusionGuide) -> None:
    cond = random_conditions(3, 64, seed=2)
    views = guide.encode_views(cond.image, cond.lighting)
    a = guide.relight_views(views)
    other = DiffusionGuide(
        guide.pipeline, DiffusionSamplingConfig(num_inference_steps=6, batch_size=3)
    )
    torch.testing.assert_close(other.relight_views(views), a, atol=1e-5, rtol=1e-5)
    assert a.shape == (3, 3, 64, 64)


def test_shared_noise_relights_identical_views_identically(guide: DiffusionGuide) -> None:
    one = random_conditions(1, 64, seed=5)
    twice = torch.cat([one.image, one.image])
    lighting = type(one.lighting)(
        ldr=torch.cat([one.lighting.ldr] * 2), hdr=torch.cat([one.lighting.hdr] * 2)
    )
    views = guide.encode_views(twice, lighting)
    per_view = guide.relight_views(views)  # seeds 0 and 1: the same view relit two ways
    assert float((per_view[0] - per_view[1]).abs().max()) > 1e-3
    shared = DiffusionGuide(
        guide.pipeline,
        DiffusionSamplingConfig(num_inference_steps=6, batch_size=2, shared_noise=True),
    )
    # encoded by the shared guide too: with latent_mode "sample" the posterior noise is per view
    same = shared.relight_views(shared.encode_views(twice, lighting))
    torch.testing.assert_close(same[0], same[1], atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(same[0], per_view[0], atol=1e-5, rtol=1e-5)  # view 0: seed 0 both


def test_denoise_from_t_star(guide: DiffusionGuide) -> None:
    cond = random_conditions(1, 64, seed=3)
    enc = guide.pipeline.encode(cond)
    x = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(4))
    out = guide.denoise_from(x, enc, 0.4, generator=torch.Generator().manual_seed(0))
    assert out.shape == (1, 3, 64, 64) and bool(torch.isfinite(out).all())
    # t* below the first step of the schedule still runs the last step (never a no-op)
    low = guide.denoise_from(x, enc, 1e-4, generator=torch.Generator().manual_seed(0))
    assert bool(torch.isfinite(low).all())
    # a no-op (returning x, or the same image whatever t*) fails here: the output is the model's,
    # it depends on how far t* noises x, and it is a function of the generator only
    assert float((out - x).abs().mean()) > 1e-3 and float((low - x).abs().mean()) > 1e-3
    assert float((out - low).abs().mean()) > 1e-4
    again = guide.denoise_from(x, enc, 0.4, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(again, out)
    sched, ts = guide.pipeline.img2img_timesteps(0.4, guide.sampling_config())
    full = sched.timesteps  # 6 "leading" steps: 834, 667, 500, 333, 167, 1
    assert ts.tolist() == [t for t in full.tolist() if t <= 400] == [333, 167, 1]


def _known_eps(value: float, seen: dict[str, object]):
    """A stand-in for the pipeline's noise prediction: `value` everywhere (NaN/Inf allowed), and a
    record of the noisy latent, timestep and guidance it was asked about."""

    def eps(
        z_t: torch.Tensor,
        t: torch.Tensor,
        enc: object,
        *,
        guidance_scale: float = 1.0,
        as_epsilon: bool = False,
    ) -> torch.Tensor:
        seen["z_t"], seen["t"], seen["guidance"] = z_t.detach().clone(), int(t), guidance_scale
        out = torch.zeros_like(z_t)
        out[0, 0] = value
        return out

    return eps


def test_sds_gradient_is_w_t_times_eps_hat_minus_eps_through_the_encoder(
    guide: DiffusionGuide, monkeypatch: pytest.MonkeyPatch
) -> None:
    # DreamFusion's SDS: d loss / d z_0 = w(t) (eps_hat(z_t) - eps), w(t) = sds_weight (1 - alpha_bar_t),
    # pushed to the image through the encoder's Jacobian. With a noise prediction we know (0.3 on
    # channel 0, 0 elsewhere) and the z_t the model was shown, eps = (z_t - sqrt(abar) z_0) /
    # sqrt(1 - abar) and the whole gradient follow; a wrong sign, weight or Jacobian fails here.
    assert guide.model.config.scheduler.prediction_type == "epsilon"  # eps_hat is the UNet output
    seen: dict[str, object] = {}
    monkeypatch.setattr(guide.pipeline, "predict_noise", _known_eps(0.3, seen))
    enc = guide.pipeline.encode(random_conditions(1, 64, seed=5))
    x = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(6)).requires_grad_()
    cfg = Stage2Config(loss="sds", sds_weight=2.0, sds_guidance_scale=1.5)
    loss = guide.sds_loss(x, enc, cfg, generator=torch.Generator().manual_seed(0))
    loss.backward()
    t = seen["t"]
    assert isinstance(t, int) and 20 <= t <= 980 and seen["guidance"] == 1.5

    x_ref = x.detach().clone().requires_grad_()
    z0 = guide.pipeline.encode_images(x_ref, enc, latent_mode="mode")
    abar = guide.pipeline.alpha_bar(torch.tensor(t))
    z_t = seen["z_t"]
    assert isinstance(z_t, torch.Tensor)
    eps = (z_t - abar.sqrt() * z0.detach()) / (1.0 - abar).sqrt()
    assert 0.5 < float(eps.std()) < 1.5  # the recovered noise is the N(0, 1) draw
    eps_hat = torch.zeros_like(z_t)
    eps_hat[0, 0] = 0.3
    g = 2.0 * (1.0 - abar) * (eps_hat - eps)
    (expected,) = torch.autograd.grad(z0, x_ref, g)
    assert x.grad is not None
    torch.testing.assert_close(x.grad, expected, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(loss.detach(), 0.5 * (g**2).sum(), rtol=1e-4, atol=1e-6)
    # and a small step against it lowers the SDS objective 0.5 ||z_0(x) - sg(z_0 - g)||^2
    target = (z0 - g).detach()
    before = float(0.5 * (g**2).sum())  # at x: z_0 - target = g
    with torch.no_grad():
        stepped = guide.pipeline.encode_images(x.detach() - 1e-3 * x.grad / x.grad.norm(), enc)
    assert float(0.5 * ((stepped - target) ** 2).sum()) < before


def test_non_finite_sds_gradients_are_zeroed_counted_and_warned_about_once(
    guide: DiffusionGuide, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    fresh = DiffusionGuide(guide.pipeline, guide.requested)
    enc = fresh.pipeline.encode(random_conditions(1, 64, seed=5))
    channel = enc.image_latents.shape[-1] ** 2  # the values of one latent channel (8 x 8)
    caplog.set_level(logging.WARNING, logger="gaffer_nerf.guidance.diffusion")
    for step, bad in enumerate((float("nan"), float("inf"))):
        monkeypatch.setattr(fresh.pipeline, "predict_noise", _known_eps(bad, {}))
        x = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(6)).requires_grad_()
        loss = fresh.sds_loss(
            x, enc, Stage2Config(loss="sds"), generator=torch.Generator().manual_seed(step)
        )
        loss.backward()
        assert bool(torch.isfinite(loss)) and x.grad is not None
        assert bool(torch.isfinite(x.grad).all())
        assert float(loss.detach()) < 1e6  # zeroed, not clamped to the largest float
    assert fresh.sds_non_finite == 2 * channel
    warned = [r for r in caplog.records if "NaN or infinite" in r.getMessage()]
    assert len(warned) == 1 and f"{channel} of {4 * channel}" in warned[0].getMessage()


def test_perceptual_loss_available_and_fallback(monkeypatch: pytest.MonkeyPatch) -> None:
    loss = load_perceptual_loss()
    assert loss.name == "stlpips-alex" and loss.available
    x = torch.rand(1, 3, 64, 64, requires_grad=True)
    d = loss(x, torch.rand(1, 3, 64, 64))
    d.backward()
    assert x.grad is not None

    def fail(*_: object) -> None:
        raise MetricUnavailableError("no weights here")

    monkeypatch.setattr(perceptual_mod, "load_perceptual", fail)
    with pytest.warns(PerceptualUnavailableWarning, match="L1 term only"):
        off = load_perceptual_loss()
    assert off.name is None and off.unavailable_reason == "no weights here" and not off.available
    assert float(off(x, x.detach())) == 0.0


def test_residual_v_prediction_model_round_trips_and_gives_sds_gradients() -> None:
    """gaffer-tiny's kind of model (pixel space, residual target, v-prediction) in the 3D guide."""
    import dataclasses

    from gaffer_diffusion import SchedulerConfig, VAEConfig, get_preset

    tiny = get_preset("tiny")
    cfg = dataclasses.replace(
        tiny,
        resolution=32,
        unet=dataclasses.replace(tiny.unet, sample_size=32),
        vae=VAEConfig(kind="pixel", scaling_factor=1.0, sample_size=32),
        scheduler=SchedulerConfig(prediction_type="v_prediction", timestep_spacing="trailing"),
        residual=True,
    )
    g = DiffusionGuide(
        RelightPipeline(build_model(cfg, seed=0)),
        DiffusionSamplingConfig(num_inference_steps=4, batch_size=2),
    )
    cond = random_conditions(2, 32, seed=7)
    enc = g.pipeline.encode(cond)
    x = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(8))
    # encode -> decode is exact in pixel space, and the input itself is the zero residual
    pipe = g.pipeline
    torch.testing.assert_close(
        pipe.decode_latents(pipe.encode_images(x, enc), enc), x, atol=1e-6, rtol=0
    )
    assert float(pipe.encode_images(cond.image, enc).abs().max()) < 1e-6
    noise = torch.randn(2, 4, 32, 32, generator=torch.Generator().manual_seed(0))
    sampling = SamplingConfig(num_inference_steps=4)
    _, ts = pipe.img2img_timesteps(1.0, sampling)
    z_t = pipe.add_noise(pipe.encode_images(x, enc), noise, ts[:1].repeat(2))
    ref = pipe.sample(enc, sampling, latents=z_t).images
    got = pipe.denoise_from(x, 1.0, enc, sampling, noise=noise)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=1e-5)
    xg = x[:1].clone().requires_grad_()
    loss = g.sds_loss(
        xg, enc.select([0]), Stage2Config(loss="sds"), generator=torch.Generator().manual_seed(0)
    )
    loss.backward()
    assert xg.grad is not None and bool(torch.isfinite(xg.grad).all())
