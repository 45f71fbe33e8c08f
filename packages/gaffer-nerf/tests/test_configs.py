"""Configs: the paper's defaults are shipped, validation names the argument, ablations, t* schedules."""

import dataclasses

import pytest

from gaffer_diffusion import PAPER_SAMPLING
from gaffer_nerf.configs import (
    ABLATIONS,
    FitConfig,
    RelightConfig,
    SceneBoxConfig,
    Stage2Config,
    fit_preset,
    relight_preset,
)
from gaffer_nerf.errors import ConfigError
from gaffer_nerf.guidance import t_star


def test_paper_defaults_match_the_reference() -> None:
    fit = fit_preset("paper")
    assert (fit.iterations, fit.batch_rays) == (30_000, 4096)
    assert (fit.initial_voxels, fit.final_voxels) == (128**3, 300**3)
    assert fit.upsample_at == (2000, 3000, 4000, 5500, 7000) and fit.alpha_mask_at == (2000, 4000)
    assert fit.tensorf.density_ranks == (16, 16, 16) and fit.tensorf.appearance_ranks == (
        48,
        48,
        48,
    )
    assert (fit.tensorf.view_pe, fit.tensorf.feature_pe) == (2, 2)
    assert (fit.l1_weight_initial, fit.l1_weight_rest) == (8e-5, 4e-5)
    assert fit.scene == SceneBoxConfig(
        aabb_min=(-1.4,) * 3, aabb_max=(1.4,) * 3, near=0.2, far=3.2, white_background=True
    )
    rel = relight_preset("paper")
    assert rel.stage1 is not None and rel.stage2 is not None
    assert (rel.stage1.iterations, rel.stage1.batch_rays) == (2500, 4096)
    assert (rel.stage1.lr_grid, rel.stage1.lr_network, rel.stage1.betas) == (
        0.02,
        1e-3,
        (0.9, 0.99),
    )
    s2 = rel.stage2
    assert (s2.iterations, s2.t_start, s2.t_end, s2.l1_weight, s2.perceptual_weight) == (
        500,
        0.4,
        0.05,
        0.5,
        0.5,
    )
    assert s2.lr_gamma == pytest.approx(0.1 ** (1 / 200)) and s2.t_schedule == "exponential"
    # sampling is the model's own unless set; a model without a suggestion gets the paper's 50 / 3
    assert (rel.diffusion.num_inference_steps, rel.diffusion.guidance_scale) == (None, None)
    paper = rel.diffusion.resolved(PAPER_SAMPLING)
    assert (paper.num_inference_steps, paper.guidance_scale, paper.compat) == (
        50,
        3.0,
        "neural-gaffer",
    )


def test_ablations() -> None:
    base = RelightConfig()
    got = {a: base.with_ablation(a) for a in ABLATIONS}
    assert got["no-stage1"].stage1 is None and got["no-stage1"].stage2.loss == "guidance"
    assert got["no-stage2"].stage2 is None and got["no-stage2"].stage1 is not None
    assert got["sds-stage2"].stage1 is not None and got["sds-stage2"].stage2.loss == "sds"
    assert got["sds-only"].stage1 is None and got["sds-only"].stage2.loss == "sds"
    assert got["no-stage2"].with_ablation("full").stage2 is not None
    with pytest.raises(ConfigError, match="ablation"):
        base.with_ablation("bogus")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="both None"):
        RelightConfig(stage1=None, stage2=None)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: SceneBoxConfig(aabb_min=(1.0, 0, 0), aabb_max=(0.0, 1, 1)), "aabb_min"),
        (lambda: SceneBoxConfig(near=2.0, far=1.0), "near"),
        (lambda: FitConfig(upsample_at=(3, 2)), "upsample_at"),
        (lambda: FitConfig(lr_grid=float("nan")), "lr_grid"),
        (lambda: FitConfig(initial_voxels=10**7, final_voxels=10**6), "initial_voxels"),
        (lambda: Stage2Config(t_start=0.05, t_end=0.4), "t_start"),
        (lambda: Stage2Config(loss="mse"), "loss"),  # type: ignore[arg-type]
    ],
)
def test_validation_names_the_argument(make, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        make()


def test_t_star_schedules() -> None:
    paper = Stage2Config()
    ts = [t_star(k, 500, paper) for k in range(500)]
    assert ts[0] == pytest.approx(0.4) and ts[-1] == pytest.approx(0.05)
    ratios = {round(ts[k + 1] / ts[k], 9) for k in range(499)}
    assert len(ratios) == 1  # exponential: constant ratio
    authors = dataclasses.replace(paper, t_schedule="authors")
    ta = [t_star(k, 500, authors) for k in range(500)]
    assert sum(0.38 <= t <= 0.4 for t in ta) == 498 and min(ta) > 0.05
    assert t_star(0, 1, paper) == 0.4
