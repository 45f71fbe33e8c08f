"""CPU timings and PSNR on the analytic sphere scene (tiny presets). Prints a markdown table.

    python packages/gaffer-nerf/scripts/bench_tiny_cpu.py [--threads 1]

Rows: fitting with the fixed (paper-style) and the footprint-sized grid; relighting with the tiny
RANDOM diffusion model (timings only: its images are noise) and with "oracle" relit views (ground-truth
renders of the training views under the target lighting in place of the diffusion model's), which
checks the Stage-1 machinery: PSNR of the relit field against the test views under the TARGET lighting.
"""

import argparse
import dataclasses
import time

import torch

from gaffer_diffusion import RelightPipeline
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf import (
    fit_preset,
    fit_tensorf,
    load_perceptual_loss,
    relight_field,
    relight_preset,
)
from gaffer_nerf.evaluate import evaluate_field
from gaffer_nerf.guidance import DiffusionGuide
from gaffer_nerf.testing import orbit_cameras, scene_envmap, sphere_viewset


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    env0, env1 = scene_envmap(0), scene_envmap(1)
    cams, tcams = orbit_cameras(8), orbit_cameras(3, offset_deg=67.0)
    train, train_t = sphere_viewset(cams, env0), sphere_viewset(cams, env1)
    test0, test1 = sphere_viewset(tcams, env0), sphere_viewset(tcams, env1)
    rows = [
        "| step | seconds | grid | grid MiB | test PSNR (dB) | against |",
        "|---|---|---|---|---|---|",
    ]
    fits = {}
    for mode in ("fixed", "footprint"):
        cfg = fit_preset("tiny")
        cfg = dataclasses.replace(cfg, sizing=dataclasses.replace(cfg.sizing, mode=mode))
        res = fit_tensorf(train, cfg)
        fits[mode] = res
        rep, _ = evaluate_field(res.field, test0, perceptual=None)
        r = res.report
        rows.append(
            f"| fit ({mode} grid, {r.iterations_run} it) | {r.seconds:.1f} | "
            f"{'x'.join(map(str, r.final_grid))} | {r.grid_bytes / 2**20:.2f} | "
            f"{rep.mean_raw.psnr:.2f} | input lighting |"
        )
    field = fits["fixed"].field
    rep, _ = evaluate_field(field, test1, perceptual=None)
    rows.append(
        f"| input field, no relighting | - | - | - | {rep.mean_raw.psnr:.2f} | target lighting |"
    )
    cfg = relight_preset("tiny")
    guide = DiffusionGuide(RelightPipeline(tiny_model()), cfg.diffusion)
    perceptual = load_perceptual_loss()
    t0 = time.perf_counter()
    res = relight_field(field, train, env1, guide, cfg, perceptual)
    r = res.report
    rows.append(
        f"| relight, random tiny model: cache {r.cache_seconds:.2f} + encode {r.encode_seconds:.2f} + "
        f"relit views {r.relight_views_seconds:.2f} + stage 1 {r.stage1.seconds:.2f} + stage 2 "
        f"{r.stage2.seconds:.2f} | {time.perf_counter() - t0:.1f} | - | - | n/a (random model) | - |"
    )
    oracle = train_t.rgb_srgb.permute(0, 3, 1, 2).contiguous()
    cfg1 = relight_preset("tiny", "no-stage2")
    for iters in (100, 500):
        c = dataclasses.replace(cfg1, stage1=dataclasses.replace(cfg1.stage1, iterations=iters))
        res = relight_field(field, train, env1, guide, c, perceptual, relit_views=oracle)
        rep, _ = evaluate_field(res.field, test1, perceptual=None)
        rows.append(
            f"| stage 1 only, oracle relit views, {iters} it | {res.report.stage1.seconds:.1f} | - | - | "
            f"{rep.mean_raw.psnr:.2f} (aligned {rep.mean_aligned_mask.psnr:.2f}) | target lighting |"
        )
    print("\n".join(rows))


if __name__ == "__main__":
    main()
