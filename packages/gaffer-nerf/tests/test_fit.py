"""Fitting: PSNR, grid schedule and shrink, footprint sizing, early stopping, rank selection, stability,
checkpoints."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from gaffer_nerf.checkpoint import load_field, save_field
from gaffer_nerf.configs import (
    RAYS_PER_CELL,
    EarlyStoppingConfig,
    GridSizingConfig,
    RankSelectionConfig,
)
from gaffer_nerf.errors import CameraError, CheckpointError, ConfigError, NonFiniteError
from gaffer_nerf.fields import EmptyAlphaMaskWarning, voxels_to_grid
from gaffer_nerf.fit import choose_rank_rung, fit_tensorf, heldout_psnr
from gaffer_nerf.rendering import render_rays_chunked
from gaffer_nerf.sizing import budget_side, choose_grid_sizing
from gaffer_nerf.testing import orbit_cameras, quick_fit_config, scene_envmap, sphere_viewset


def test_fit_reaches_a_useful_psnr_and_shrinks_the_box(fitted, scene) -> None:
    rep = fitted.report
    psnr = heldout_psnr(fitted.field, scene.test_input.cameras.rays(), scene.test_input.rgb_flat())
    assert psnr > 22.0, psnr  # ~26 dB in ~4 s on one core; a blank white image scores ~9 dB
    assert rep.iterations_run == 120 and not rep.stopped_early
    # the box never grows, and the first alpha mask's shrink kept the sphere (radius 0.5) inside it
    box = fitted.field.aabb
    assert float(box.min()) >= -1.0 and float(box.max()) <= 1.0
    assert bool((box[0] <= -0.45).all()) and bool((box[1] >= 0.45).all()), box
    assert len(rep.grid_history) == 4 and rep.final_grid == fitted.field.grid_size
    assert rep.grid_bytes == fitted.field.grid_memory_bytes() > 0


@pytest.mark.parametrize("seed", [0, 1])
def test_alpha_mask_shrinks_the_box_to_the_object(scene, seed: int) -> None:
    # How far the box shrinks at TensoRF's threshold (alpha 1e-4) depends on which faint floaters 40
    # steps leave: measured over seeds 0-3, the box side stays 2.0 on seed 1 at every density L1 tried
    # (0 to 8e-5). With a threshold that ignores faint floaters (3e-3), what is left is the shrink
    # itself: on seeds 0-3 the box closes to +-0.6, the sphere (radius 0.5) plus the mask's one-voxel
    # margin. (At 1e-2 it cuts into the sphere's still-faint edge on three of the four seeds.)
    base = quick_fit_config(seed=seed)
    cfg = dataclasses.replace(
        base, tensorf=dataclasses.replace(base.tensorf, alpha_mask_threshold=3e-3)
    )
    res = fit_tensorf(scene.train, cfg)
    box = res.field.aabb
    assert float((box[1] - box[0]).max()) < 1.5, box
    assert bool((box[0] <= -0.5).all()) and bool((box[1] >= 0.5).all()), box
    psnr = heldout_psnr(res.field, scene.test_input.cameras.rays(), scene.test_input.rgb_flat())
    assert psnr > 22.0, psnr


def test_footprint_sizing_and_cap() -> None:
    cams = orbit_cameras(4, resolution=64, distance=2.5, fov_deg=40.0)
    box = torch.tensor([[-1.0] * 3, [1.0] * 3])
    s = choose_grid_sizing(cams, box, GridSizingConfig(mode="footprint"))
    f = 32 / math.tan(math.radians(20))
    assert s.footprint == pytest.approx(2.5 / f, rel=1e-5) and s.voxel_size == pytest.approx(
        s.footprint
    )
    sizing = GridSizingConfig(mode="footprint", max_resolution=300, rays_per_cell=None)
    cfg = quick_fit_config(sizing=sizing)
    grid = s.final_grid(box, cfg)
    assert grid[0] == math.ceil(2.0 / s.voxel_size) + 1  # ~71 for a 64 px capture, not 300
    capped = quick_fit_config(
        sizing=GridSizingConfig(mode="footprint", max_resolution=20, rays_per_cell=None)
    )
    assert s.final_grid(box, capped) == (20, 20, 20)
    # the iteration budget: 120 x 512 rays at 768 rays per plane cell train ~8.9^3
    budget = quick_fit_config(sizing=GridSizingConfig(mode="footprint", min_resolution=4))
    assert budget_side(budget) == pytest.approx(math.sqrt(120 * 512 / RAYS_PER_CELL))
    assert s.final_grid(box, budget) == voxels_to_grid(round(budget_side(budget) ** 3), box)
    longer = dataclasses.replace(budget, iterations=120 * 128)  # ~100 per axis: the footprint binds
    assert s.final_grid(box, longer) == grid
    fixed = choose_grid_sizing(cams, box, GridSizingConfig())
    assert fixed.voxel_size is None and fixed.final_grid(box, cfg) == voxels_to_grid(24**3, box)


def test_footprint_mode_fits(scene) -> None:
    cfg = quick_fit_config(
        iterations=60,
        alpha_mask_at=(40,),
        sizing=GridSizingConfig(
            mode="footprint", oversample=0.5, max_resolution=48, min_resolution=4
        ),
    )
    res = fit_tensorf(scene.train, cfg)
    assert res.report.sizing.mode == "footprint"
    assert (
        max(res.report.final_grid)
        <= math.ceil(float(res.field.aabb_size.max()) / res.report.sizing.voxel_size) + 1
    )


def test_early_stopping_stops_on_a_plateau(scene) -> None:
    es = EarlyStoppingConfig(
        eval_every=10, patience=2, min_delta_db=50.0, max_rays=500, min_iterations=20
    )
    res = fit_tensorf(scene.train, quick_fit_config(early_stopping=es), heldout=scene.test_input)
    assert res.report.stopped_early and res.report.iterations_run == 30
    assert [h.iteration for h in res.report.heldout] == [10, 20, 30]
    with pytest.raises(ConfigError, match="heldout"):
        fit_tensorf(scene.train, quick_fit_config(early_stopping=es))


def test_rank_selection_fits_the_ladder_and_keeps_the_rung_it_chose() -> None:
    # Whether doubling the ranks pays on this sphere at 120 steps is seed luck: measured against 4/8
    # (~27 dB), the 8/16 rung scored +2.5 dB on seed 0 and +0.1 on seed 1 with the tiny preset's
    # density L1, and -0.8 / +1.0 dB with TensoRF's (8e-5 / 4e-5). So this test fixes the
    # choice with a tolerance no rung can beat (50 dB) and checks the ladder around it: the rungs'
    # ranks and sizes, that it stops after two fits without trying x4, and that the field returned is
    # the chosen rung's. `choose_rank_rung` itself is tested on given PSNRs below.
    env = scene_envmap(0)
    train = sphere_viewset(orbit_cameras(8), env, plain=True)
    heldout = sphere_viewset(orbit_cameras(3, offset_deg=67.0), env, plain=True)
    sel = RankSelectionConfig(ladder=(1.0, 2.0, 4.0), tolerance_db=50.0, max_rays=4000)
    res = fit_tensorf(train, quick_fit_config(rank_selection=sel), heldout=heldout)
    rs = res.report.rank_selection
    assert rs is not None and rs.chosen == 0 and len(rs.rungs) == 2, rs
    assert rs.chosen == choose_rank_rung([r.heldout_psnr for r in rs.rungs], sel.tolerance_db)
    small, large = rs.rungs
    assert (small.density_ranks, small.appearance_ranks) == ((4, 4, 4), (8, 8, 8))
    assert (large.density_ranks, large.appearance_ranks) == ((8, 8, 8), (16, 16, 16))
    assert small.heldout_psnr > 24.0 and large.heldout_psnr > 24.0
    assert 0 < small.parameters < large.parameters and 0 < small.memory_mib < large.memory_mib
    assert all(r.seconds > 0 and r.iterations_run == 120 for r in rs.rungs)
    assert res.field.config.density_ranks == (4, 4, 4) and rs.chosen_rung is small
    assert res.report.seconds >= small.seconds + large.seconds
    assert res.report.final_grid == res.field.grid_size
    with pytest.raises(ConfigError, match="rank_selection"):
        fit_tensorf(train, quick_fit_config(rank_selection=sel))


def test_choose_rank_rung_and_ladder_validation() -> None:
    assert choose_rank_rung([20.0, 24.0, 24.1, 30.0], 0.25) == 1  # the first plateau wins
    assert choose_rank_rung([20.0, 24.0, 26.0], 0.25) is None  # still climbing: fit more
    assert choose_rank_rung([20.0, 19.0], 0.0) == 0  # a worse larger rung never wins
    assert choose_rank_rung([20.0], 0.25) is None
    assert RankSelectionConfig.scaled_ranks((4, 4, 4), 0.1) == (1, 1, 1)
    for bad, match in (((), "empty"), ((1.0, 0.5), "increasing"), ((0.0, 1.0), "ladder")):
        with pytest.raises(ConfigError, match=match):
            RankSelectionConfig(ladder=bad)
    with pytest.raises(ConfigError, match="tolerance_db"):
        RankSelectionConfig(tolerance_db=-1.0)


def test_scene_without_object_gives_an_empty_mask_and_white_renders() -> None:
    cams = orbit_cameras(4, resolution=24)
    empty = sphere_viewset(cams, scene_envmap(0), empty=True)
    cfg = quick_fit_config(iterations=45, upsample_at=(30,), alpha_mask_at=(20, 40))
    with pytest.warns(EmptyAlphaMaskWarning):
        res = fit_tensorf(empty, cfg)
    out = render_rays_chunked(res.field, cams.rays([0]))
    assert float(out.rgb.min()) > 0.98


def test_degenerate_inputs_raise(scene) -> None:
    coincident = dataclasses.replace(
        scene.train,
        cameras=dataclasses.replace(
            scene.train.cameras, c2w_opencv=scene.train.cameras.c2w_opencv[:1].repeat(8, 1, 1)
        ),
    )
    with pytest.raises(CameraError, match="coincide"):
        fit_tensorf(coincident, quick_fit_config(iterations=2))
    nan_images = dataclasses.replace(
        scene.train, rgb_srgb=torch.full_like(scene.train.rgb_srgb, float("nan"))
    )
    with pytest.raises(NonFiniteError, match="iteration 1"):
        fit_tensorf(nan_images, quick_fit_config(iterations=2))


def test_checkpoint_round_trip(fitted, tmp_path: Path) -> None:
    save_field(fitted.field, tmp_path / "f")
    back = load_field(tmp_path / "f")
    assert back.grid_size == fitted.field.grid_size
    torch.testing.assert_close(back.aabb, fitted.field.aabb)
    assert back.alpha_volume is not None
    rays = orbit_cameras(1, resolution=16).rays()
    torch.testing.assert_close(
        render_rays_chunked(back, rays).rgb, render_rays_chunked(fitted.field, rays).rgb
    )
    (tmp_path / "g").mkdir()
    with pytest.raises(CheckpointError, match=r"config\.json"):
        load_field(tmp_path / "g")
