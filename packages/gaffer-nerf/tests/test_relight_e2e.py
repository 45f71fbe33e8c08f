"""End to end on CPU: fit -> Stage 1 -> Stage 2 -> evaluate (tiny scene, tiny random diffusion model)."""

import dataclasses
import math
import time

import pytest
import torch

import gaffer_nerf.guidance.perceptual as perceptual_mod
from gaffer_diffusion import RelightPipeline
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf.configs import relight_preset
from gaffer_nerf.evaluate import evaluate_field
from gaffer_nerf.fit import fit_tensorf
from gaffer_nerf.guidance import DiffusionGuide, load_perceptual_loss, unavailable_perceptual
from gaffer_nerf.guidance.diffusion import t_star
from gaffer_nerf.relight import relight_field
from gaffer_nerf.rendering import build_weight_cache, render_cached
from gaffer_nerf.testing import quick_fit_config


def _guide(cfg) -> DiffusionGuide:
    return DiffusionGuide(RelightPipeline(tiny_model()), cfg.diffusion)


def test_end_to_end_under_a_minute(scene) -> None:
    t0 = time.perf_counter()
    fit = fit_tensorf(scene.train, quick_fit_config())
    cfg = relight_preset("tiny")
    guide = _guide(cfg)
    res = relight_field(
        fit.field, scene.train, scene.env_target, guide, cfg, load_perceptual_loss()
    )
    report, pred = evaluate_field(res.field, scene.test_target)
    elapsed = time.perf_counter() - t0
    assert elapsed < 60.0, elapsed
    r = res.report
    assert r.stage1 is not None and r.stage2 is not None
    assert r.stage1.iterations == 100 and r.stage2.iterations == 6
    assert all(torch.isfinite(torch.tensor(r.stage1.losses))) and all(
        torch.isfinite(torch.tensor(r.stage2.losses))
    )
    assert r.stage1.losses[-1] < r.stage1.losses[0]  # the appearance fits the relit views
    assert r.stage2.t_star[0] == pytest.approx(0.4) and r.stage2.t_star[-1] == pytest.approx(0.05)
    assert r.perceptual_name == "stlpips-alex"
    assert res.relit_views is not None and res.relit_views.shape == (8, 3, 64, 64)
    assert pred.shape == (3, 3, 64, 64) and report.mean_aligned_mask is not None
    assert report.perceptual_name == "stlpips-alex" and len(report.items) == 3
    # the density is untouched and the input field is unchanged
    for a, b in zip(res.field.density_parameters(), fit.field.density_parameters(), strict=True):
        assert torch.equal(a, b)
    assert not all(
        torch.equal(a, b)
        for a, b in zip(res.field.network_parameters(), fit.field.network_parameters(), strict=True)
    )
    # Stage 1 fitted the relit views: the relit field renders closer to them than the input field
    cache = build_weight_cache(res.field, scene.train.cameras.rays([0]))
    ids = torch.arange(cache.num_rays)
    target = res.relit_views[0].permute(1, 2, 0).reshape(-1, 3)
    with torch.no_grad():
        err_relit = float((render_cached(res.field, cache, ids) - target).abs().mean())
        err_input = float((render_cached(fit.field, cache, ids) - target).abs().mean())
    assert err_relit < err_input


@pytest.mark.parametrize("ablation", ["no-stage1", "no-stage2", "sds-stage2", "sds-only"])
def test_ablations_run(fitted, scene, ablation: str) -> None:
    cfg = relight_preset("tiny", ablation)  # type: ignore[arg-type]
    if cfg.stage1 is not None:
        cfg = dataclasses.replace(cfg, stage1=dataclasses.replace(cfg.stage1, iterations=10))
    if cfg.stage2 is not None:
        cfg = dataclasses.replace(cfg, stage2=dataclasses.replace(cfg.stage2, iterations=2))
    relit = torch.rand(
        8, 3, 64, 64, generator=torch.Generator().manual_seed(0)
    )  # reuse: skip sampling
    res = relight_field(
        fitted.field, scene.train, scene.env_target, _guide(cfg), cfg,
        unavailable_perceptual("not requested"), relit_views=relit,
    )  # fmt: skip
    r = res.report
    assert (r.stage1 is None) == (ablation in ("no-stage1", "sds-only"))
    assert (r.stage2 is None) == (ablation == "no-stage2")
    if r.stage2 is not None:
        assert r.stage2.loss_kind == ("sds" if "sds" in ablation else "guidance")
        # SDS draws its timesteps at random and records none; the guidance loss records the t* of
        # each step, which follows the configured schedule (0.4 -> 0.05 over the 2 steps here)
        expected = (
            ()
            if "sds" in ablation
            else tuple(t_star(k, cfg.stage2.iterations, cfg.stage2) for k in range(2))
        )
        assert r.stage2.t_star == pytest.approx(expected), r.stage2.t_star
        if expected:
            assert expected == pytest.approx((0.4, 0.05))
    assert r.relight_views_seconds == 0.0
    if r.stage2 is not None:
        assert r.stage2.sds_non_finite == 0  # a healthy model: nothing zeroed


def test_sds_stage_reports_the_non_finite_gradient_values_it_zeroed(
    fitted, scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = relight_preset("tiny", "sds-only")
    assert cfg.stage2 is not None
    cfg = dataclasses.replace(cfg, stage2=dataclasses.replace(cfg.stage2, iterations=3))
    guide = _guide(cfg)
    calls = {"n": 0}

    def one_nan(z_t: torch.Tensor, *_: object, **__: object) -> torch.Tensor:
        calls["n"] += 1
        out = torch.zeros_like(z_t)
        out[0, 0, 0, 0] = float("nan")  # one bad value per SDS evaluation
        return out

    monkeypatch.setattr(guide.pipeline, "predict_noise", one_nan)
    res = relight_field(
        fitted.field, scene.train, scene.env_target, guide, cfg,
        unavailable_perceptual("not requested"),
    )  # fmt: skip
    s2 = res.report.stage2
    assert s2 is not None and all(math.isfinite(v) for v in s2.losses)
    assert calls["n"] >= 3 and s2.sds_non_finite == calls["n"] == guide.sds_non_finite


def test_authors_schedule_and_perceptual_fallback(
    fitted, scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = relight_preset("tiny", "no-stage1")
    cfg = dataclasses.replace(
        cfg, stage2=dataclasses.replace(cfg.stage2, iterations=3, t_schedule="authors")
    )

    def fail(*_: object) -> None:
        from gaffer_diffusion.errors import MetricUnavailableError

        raise MetricUnavailableError("offline weights missing")

    monkeypatch.setattr(perceptual_mod, "load_perceptual", fail)
    with pytest.warns(perceptual_mod.PerceptualUnavailableWarning):
        perceptual = load_perceptual_loss()
    res = relight_field(fitted.field, scene.train, scene.env_target, _guide(cfg), cfg, perceptual)
    assert res.report.perceptual_name is None
    assert res.report.perceptual_unavailable_reason == "offline weights missing"
    assert res.report.stage2 is not None and res.report.stage2.t_star[0] > 0.38


def test_framed_stage1_fits_the_relit_crops_pasted_into_the_frames(fitted, scene) -> None:
    """With object-centred framing, Stage 1's targets are the model's crops put back in their boxes,
    white outside; `stage1_targets` are frames used as they are; both at once are refused."""
    from gaffer_nerf.configs import DiffusionSamplingConfig
    from gaffer_nerf.errors import ConfigError

    cfg = relight_preset("tiny", "no-stage2")
    assert cfg.stage1 is not None
    cfg = dataclasses.replace(
        cfg,
        stage1=dataclasses.replace(cfg.stage1, iterations=200),
        diffusion=DiffusionSamplingConfig(object_fraction=0.75, num_inference_steps=2),
    )
    guide = _guide(cfg)
    assert scene.train.alpha is not None
    framing = guide.framing(scene.train.alpha)
    assert framing is not None
    crops = torch.full((8, 3, 64, 64), 0.2)  # a dark object where the model would put it
    res = relight_field(
        fitted.field, scene.train, scene.env_target, guide, cfg,
        unavailable_perceptual("not requested"), relit_views=crops,
    )  # fmt: skip
    assert res.relit_views is crops
    images = scene.train.rgb_srgb.permute(0, 3, 1, 2)
    target = framing.paste(crops, list(range(8)), images)
    cache = build_weight_cache(res.field, scene.train.cameras.rays([0]))
    with torch.no_grad():
        render = render_cached(res.field, cache, torch.arange(cache.num_rays))
    err = float((render - target[0].permute(1, 2, 0).reshape(-1, 3)).abs().mean())
    err_unpasted = float((render - 0.2).abs().mean())  # the crops read as whole frames
    assert err < err_unpasted
    with pytest.raises(ConfigError, match="not both"):
        relight_field(
            fitted.field, scene.train, scene.env_target, guide, cfg,
            unavailable_perceptual("not requested"), relit_views=crops, stage1_targets=images,
        )  # fmt: skip
