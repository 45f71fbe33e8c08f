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
    # The first alpha mask (the preset's threshold, alpha 1e-4) shrinks the box: the box never grows,
    # at least one face moves in by a voxel of the 12^3 grid (0.2), and the sphere (radius 0.5) stays
    # inside. How far it shrinks is seed luck at 1e-4: faint floaters hold faces out; measured over
    # seeds 0-5, the volume fell from 8 to 2.7-7.2 (seed 1 moved only the -z face, 2 x 2 x 1.8), so
    # 7.2 is the bound every seed meets. The shrink to the sphere itself is tested below at 3e-3.
    box = fitted.field.aabb
    assert float(box.min()) >= -1.0 and float(box.max()) <= 1.0
    assert float((box[1] - box[0]).prod()) <= 2.0 * 2.0 * 1.8 + 1e-4, box
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


def test_rank_selection_climbs_past_a_starved_rung_and_stops_where_doubling_gains_little(
    scene,
) -> None:
    # Tolerances the scores decide. Measured on this painted sphere at 120 steps, seeds 0-3, on the
    # same 4000 held-out rays: 1/1 ranks 22.5-23.7 dB, 4/8 26.0-28.0, 8/16 27.9-29.9. 4/8 beats 1/1
    # by 3.1-5.4 dB, so at the default tolerance (0.25 dB) the climb must go past 1/1. 8/16 beats 4/8
    # by 0.6-2.0 dB (on the unpainted sphere -1.0 to +2.5: seed luck), so with 3 dB (what a starved
    # rung loses) the climb must stop at 4/8, after two fits, without trying x4.
    climb = RankSelectionConfig(ladder=(0.125, 1.0), tolerance_db=0.25, max_rays=4000)
    res = fit_tensorf(scene.train, quick_fit_config(rank_selection=climb), heldout=scene.test_input)
    rs = res.report.rank_selection
    assert rs is not None and rs.chosen == 1 and len(rs.rungs) == 2, rs
    starved, kept = rs.rungs
    assert (starved.density_ranks, starved.appearance_ranks) == ((1, 1, 1), (1, 1, 1))
    assert kept.heldout_psnr > starved.heldout_psnr + 2.0, rs  # far above the tolerance
    assert res.field.config.appearance_ranks == (8, 8, 8) and rs.chosen_rung is kept

    stop = RankSelectionConfig(ladder=(1.0, 2.0, 4.0), tolerance_db=3.0, max_rays=4000)
    res = fit_tensorf(scene.train, quick_fit_config(rank_selection=stop), heldout=scene.test_input)
    rs = res.report.rank_selection
    assert rs is not None and rs.chosen == 0 and len(rs.rungs) == 2, rs
    assert rs.chosen == choose_rank_rung([r.heldout_psnr for r in rs.rungs], stop.tolerance_db)
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
        fit_tensorf(scene.train, quick_fit_config(rank_selection=stop))


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
