"""The stability list (where a method could break), end to end. Cases tested elsewhere, at the layer that owns them:

- empty alpha mask of the field: `test_tensorf.py::test_alpha_mask_finds_a_blob_and_empty_mask_is_refused`;
- a scene with no object, fitting: `test_fit.py::test_scene_without_object_gives_an_empty_mask_and_white_renders`;
- degenerate cameras: `test_cameras.py` (NaN, scale, reflection, last row, coincident centres, focal),
  `test_data.py::test_reader_errors` (NaN pose in a transforms file), `test_fit.py::test_degenerate_inputs_raise`;
- NaN guard in TV / regularisers: `test_tensorf.py::test_regularisers_nan_guard_and_degenerate_planes`;
- LPIPS unavailable in the Stage-2 loss: `test_guidance.py::test_perceptual_loss_available_and_fallback`,
  `test_relight_e2e.py::test_authors_schedule_and_perceptual_fallback`.

Here: the rest of the chain on the same cases (relighting and scoring an empty scene, empty ground-truth
masks, the evaluation metric without LPIPS), each labelled rather than silently wrong.
"""

import dataclasses
import json

import pytest
import torch

import gaffer_diffusion.metrics as metrics_mod
from gaffer_diffusion import RelightPipeline
from gaffer_diffusion.errors import MetricUnavailableError
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf.configs import relight_preset
from gaffer_nerf.evaluate import EmptyMaskWarning, evaluate_field
from gaffer_nerf.fields import EmptyAlphaMaskWarning
from gaffer_nerf.fit import FitResult, fit_tensorf
from gaffer_nerf.guidance import DiffusionGuide, unavailable_perceptual
from gaffer_nerf.relight import NothingToRelightWarning, relight_field
from gaffer_nerf.testing import orbit_cameras, quick_fit_config, scene_envmap, sphere_viewset


@pytest.fixture(scope="module")
def empty_fit() -> tuple[FitResult, object]:
    cams = orbit_cameras(4, resolution=24)
    views = sphere_viewset(cams, scene_envmap(0), empty=True)
    cfg = quick_fit_config(iterations=45, upsample_at=(30,), alpha_mask_at=(20, 40))
    with pytest.warns(EmptyAlphaMaskWarning):
        return fit_tensorf(views, cfg), views


def test_relighting_a_scene_with_no_object_warns_and_changes_nothing(empty_fit) -> None:
    fit, views = empty_fit
    cfg = relight_preset("tiny")
    cfg = dataclasses.replace(
        cfg,
        stage1=dataclasses.replace(cfg.stage1, iterations=3),
        stage2=dataclasses.replace(cfg.stage2, iterations=2),
        diffusion=dataclasses.replace(cfg.diffusion, num_inference_steps=2),
    )
    guide = DiffusionGuide(RelightPipeline(tiny_model()), cfg.diffusion)
    with pytest.warns(NothingToRelightWarning, match="nothing|no appearance"):
        res = relight_field(
            fit.field, views, scene_envmap(1), guide, cfg, unavailable_perceptual("test")
        )
    r = res.report
    assert r.cache_samples == 0 and r.stage1 is not None and r.stage2 is not None
    assert all(torch.isfinite(torch.tensor([*r.stage1.losses, *r.stage2.losses])))
    for a, b in zip(res.field.parameters(), fit.field.parameters(), strict=True):
        assert torch.equal(a, b)


def test_scoring_against_empty_masks_is_labelled(empty_fit, scene, fitted) -> None:
    fit, views = empty_fit
    # every mask empty: no mask-aligned row (a zero-pixel fit would score a black image)
    with pytest.warns(EmptyMaskWarning, match="Every"):
        report, _ = evaluate_field(fit.field, views, perceptual=None)
    assert report.mean_aligned_mask is None and report.mean_raw.psnr > 30.0  # white on white
    # one empty mask among object views: that view is aligned over the whole image, named
    gt = scene.test_target
    alpha = gt.alpha.clone()
    alpha[1] = 0.0
    with pytest.warns(EmptyMaskWarning, match=gt.names[1]):
        mixed, _ = evaluate_field(
            fitted.field, dataclasses.replace(gt, alpha=alpha), perceptual=None
        )
    assert mixed.items[1].aligned_mask == mixed.items[1].aligned_image
    assert mixed.items[0].aligned_mask is not None and mixed.items[0].aligned_mask.psnr > 5.0


def test_evaluation_without_lpips_falls_back_labelled(
    fitted, scene, monkeypatch: pytest.MonkeyPatch
) -> None:
    def fail(*_: object) -> None:
        raise MetricUnavailableError("stlpips weights not installed")

    monkeypatch.setattr(metrics_mod, "load_perceptual", fail)
    report, _ = evaluate_field(fitted.field, scene.test_target)
    assert report.perceptual_name is None
    assert report.perceptual_unavailable_reason == "stlpips weights not installed"
    assert all(i.raw.perceptual is None for i in report.items)
    assert "unavailable: stlpips weights not installed" in report.to_markdown()
    assert json.loads(report.to_json())["perceptual_name"] is None
