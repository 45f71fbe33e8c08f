"""gaffer-nerf on the CPU: fitting speed vs accuracy per grid size, and Stage 1 / Stage 2 relighting timings.

The scene is `gaffer_nerf.testing`'s analytic sphere (64x64 px views, 8 training and 3 test cameras on an
orbit, two random smooth environment maps `scene_envmap(0)` = input lighting, `scene_envmap(1)` = target
lighting); every model is the "tiny" preset (`fit_preset("tiny")`, `relight_preset("tiny")`).

Two parts, one JSON + PNG (`nerf`, see `_common.write_results`):

1. Fitting (`fit_tensorf`, 300 iterations of 1024 rays): the paper's *fixed* final voxel count (the tiny
   preset's 32^3, and smaller and larger counts) against the *footprint-sized* grid (voxel = the finest
   camera's pixel footprint at the object / `oversample`; `max_resolution` raised to 96 so that the
   footprint, not the cap, sets the size). Per fit: seconds, final grid, factor-grid MiB, and the PSNR of
   the field's renders of the held-out test views (input lighting).
2. Relighting the fixed-32^3 field under the target lighting:
   - the whole `relight_field` with the tiny RANDOM diffusion model (`gaffer_nerf.guidance.smoke_model`,
     sampled with 10 DDIM steps, set explicitly since the random model suggests none of its own):
     timings per phase only (weight cache, encoding, relit views, Stage 1, Stage 2); its images are noise,
     so no accuracy is reported for it;
   - Stage 1 alone with "oracle" relit views (ground-truth renders of the training views under the target
     lighting in place of the diffusion model's) at a few iteration counts: this checks the Stage-1
     machinery, as PSNR of the relit field against the test views under the TARGET lighting (raw, and
     after the per-channel scale alignment in the object mask that the paper's metrics use). The
     unrelit input field against the same views is the floor.

No trained tiny diffusion model exists yet, so relighting *quality* with the real prior is not measured.

Run: `python benchmarks/bench_nerf.py [--quick] [--update-baseline] [--threads N] [--seed S]`.
Default threads here is 1 (the scene is too small for torch's intra-op threads to pay off, and 1 thread
leaves the other core to whatever shares the machine). The default run takes about 4 minutes on one
thread; `--quick` under a minute and a half.
"""

import dataclasses
import sys
import time
from collections.abc import Sequence
from typing import Any

import _common as common

NAME = "nerf"
FIXED_SIDES = (16, 24, 32, 48)  # fixed final grid: side**3 voxels (32 = the tiny preset)
FIXED_SIDES_QUICK = (24, 32)
OVERSAMPLES = (0.5, 1.0, 2.0)  # footprint-sized grid: voxels per pixel footprint
OVERSAMPLES_QUICK = (0.5, 1.0)
STAGE1_ITERS = (100, 300, 1000)  # the tiny preset's Stage 1 is 100 iterations
STAGE1_ITERS_QUICK = (100,)
FOOTPRINT_MAX_RESOLUTION = 96


def _psnr(report: Any) -> float:
    return round(float(report.mean_raw.psnr), 3)


def run_fits(quick: bool, seed: int, train: Any, test: Any) -> tuple[list[dict[str, Any]], Any]:
    """Fit the same views with each grid choice; return the rows and the fixed-32^3 field."""
    from gaffer_nerf import fit_preset, fit_tensorf
    from gaffer_nerf.evaluate import evaluate_field

    base = fit_preset("tiny")
    base = dataclasses.replace(base, seed=seed)
    variants: list[tuple[str, Any, dict[str, Any]]] = []
    for side in FIXED_SIDES_QUICK if quick else FIXED_SIDES:
        cfg = dataclasses.replace(
            base, final_voxels=side**3, initial_voxels=min(base.initial_voxels, side**3)
        )
        variants.append((f"fixed {side}^3", cfg, {"mode": "fixed", "final_voxels": side**3}))
    for over in OVERSAMPLES_QUICK if quick else OVERSAMPLES:
        sizing = dataclasses.replace(
            base.sizing,
            mode="footprint",
            oversample=over,
            max_resolution=FOOTPRINT_MAX_RESOLUTION,
        )
        cfg = dataclasses.replace(base, sizing=sizing)
        variants.append((f"footprint x{over:g}", cfg, {"mode": "footprint", "oversample": over}))
    rows: list[dict[str, Any]] = []
    keep = None
    for label, cfg, params in variants:
        res = fit_tensorf(train, cfg)
        rep, _ = evaluate_field(res.field, test, perceptual=None)
        r = res.report
        rows.append(
            {
                "label": label,
                **params,
                "iterations": r.iterations_run,
                "seconds": round(r.seconds, 3),
                "final_grid": list(r.final_grid),
                "grid_mib": round(r.grid_bytes / 2**20, 4),
                "test_psnr_db": _psnr(rep),
                "footprint_world": round(r.sizing.footprint, 5),
            }
        )
        common.log(
            f"  fit {label:<16} {r.seconds:6.1f} s  grid {'x'.join(map(str, r.final_grid)):<9} "
            f"{r.grid_bytes / 2**20:6.3f} MiB  test PSNR {_psnr(rep):.2f} dB"
        )
        if label == "fixed 32^3":
            keep = res.field
    return rows, keep


def run_relight(
    quick: bool, field: Any, train: Any, train_target: Any, test_target: Any, env1: Any
) -> dict[str, Any]:
    """Phase timings with the random tiny model; Stage 1 with oracle relit views against the target."""
    from gaffer_diffusion import RelightPipeline
    from gaffer_nerf import load_perceptual_loss, relight_field, relight_preset
    from gaffer_nerf.evaluate import evaluate_field
    from gaffer_nerf.guidance import DiffusionGuide, smoke_model

    floor, _ = evaluate_field(field, test_target, perceptual=None)
    cfg = relight_preset("tiny")
    cfg = dataclasses.replace(
        cfg, diffusion=dataclasses.replace(cfg.diffusion, num_inference_steps=10)
    )
    guide = DiffusionGuide(RelightPipeline(smoke_model()), cfg.diffusion)
    perceptual = load_perceptual_loss()
    t0 = time.perf_counter()
    res = relight_field(field, train, env1, guide, cfg, perceptual)
    wall = time.perf_counter() - t0
    r = res.report
    assert r.stage1 is not None and r.stage2 is not None  # the "full" ablation runs both
    phases = {
        "cache": round(r.cache_seconds, 3),
        "encode": round(r.encode_seconds, 3),
        "relit views": round(r.relight_views_seconds, 3),
        "stage 1": round(r.stage1.seconds, 3),
        "stage 2": round(r.stage2.seconds, 3),
    }
    common.log(f"  relight, random tiny model: {phases} (wall {wall:.1f} s)")
    full = {
        "model": "tiny random-init (gaffer_nerf.guidance.smoke_model)",
        "stage1_iterations": r.stage1.iterations,
        "stage2_iterations": r.stage2.iterations,
        "num_inference_steps": guide.sampling.num_inference_steps,
        "training_views": train.cameras.num_views,
        "perceptual": r.perceptual_name or f"none ({r.perceptual_unavailable_reason})",
        "phase_seconds": phases,
        "stage2_seconds_per_iteration": round(r.stage2.seconds / max(r.stage2.iterations, 1), 3),
        "total_seconds": round(r.total_seconds, 3),
    }
    oracle = train_target.rgb_srgb.permute(0, 3, 1, 2).contiguous()  # [V, 3, H, W]
    cfg1 = relight_preset("tiny", "no-stage2")
    assert cfg1.stage1 is not None
    stage1_rows = []
    for iters in STAGE1_ITERS_QUICK if quick else STAGE1_ITERS:
        c = dataclasses.replace(cfg1, stage1=dataclasses.replace(cfg1.stage1, iterations=iters))
        res1 = relight_field(field, train, env1, guide, c, perceptual, stage1_targets=oracle)
        rep, _ = evaluate_field(res1.field, test_target, perceptual=None)
        assert res1.report.stage1 is not None
        secs = res1.report.stage1.seconds
        stage1_rows.append(
            {
                "iterations": iters,
                "seconds": round(secs, 3),
                "test_psnr_db": _psnr(rep),
                "test_psnr_aligned_db": round(float(rep.mean_aligned_mask.psnr), 3),
            }
        )
        common.log(
            f"  stage 1, oracle relit views, {iters:>4} it: {secs:5.1f} s, target PSNR "
            f"{_psnr(rep):.2f} dB (aligned {rep.mean_aligned_mask.psnr:.2f})"
        )
    return {
        "input_field_vs_target": {
            "test_psnr_db": _psnr(floor),
            "test_psnr_aligned_db": round(float(floor.mean_aligned_mask.psnr), 3),
        },
        "full_relight_random_model": full,
        "stage1_oracle": stage1_rows,
    }


FLICKER_FRAMES = 16  # the test orbit: 22.5 degrees a frame, constant elevation, a closed loop
FLICKER_FRAMES_QUICK = 8
FLICKER_STAGE1_ITERS = 300


def _masked_psnr(pred: Any, gt: Any, alpha: Any) -> float:
    """PSNR over the object mask (alpha-weighted), [T, 3, H, W] against [T, 3, H, W]."""
    import math

    w = alpha.unsqueeze(1).double()
    mse = float(((pred.double() - gt.double()).square() * w).sum() / (3 * w.sum()))
    return round(10 * math.log10(1.0 / max(mse, 1e-12)), 3)


def run_flicker(
    quick: bool,
    field: Any,
    train: Any,
    env0: Any,
    env1: Any,
    models: Sequence[str] = ("gaffer-tiny",),
) -> dict[str, Any]:
    """Multi-view consistency along a closed test orbit under the target lighting.

    2D: every orbit frame of the input lighting relit by the diffusion model as Stage 1 relights its
    training views, per-view vs shared initial noise, mirror average off / on; `temporal_flicker`
    against the ground-truth orbit (the analytic sphere under the target lighting), and the masked PSNR.
    3D: Stage 1 alone (its targets with per-view vs shared noise), the relit field rendered along the
    same orbit. The unrelit input orbit is the reference a relighting should not flicker more than.
    """
    import torch
    import torch.nn.functional as F

    from gaffer_diffusion import RelightPipeline
    from gaffer_nerf import load_perceptual_loss, relight_field, relight_preset
    from gaffer_nerf.evaluate import render_views
    from gaffer_nerf.flicker import temporal_flicker
    from gaffer_nerf.guidance import DiffusionGuide, load_relighting_model
    from gaffer_nerf.testing import sphere_viewset
    from gaffer_nerf.video import orbit_path

    orbit = orbit_path(train.cameras, FLICKER_FRAMES_QUICK if quick else FLICKER_FRAMES)
    gt_set, inp_set = sphere_viewset(orbit, env1), sphere_viewset(orbit, env0)
    gt = gt_set.rgb_srgb.permute(0, 3, 1, 2).contiguous()
    inputs = inp_set.rgb_srgb.permute(0, 3, 1, 2).contiguous()
    alpha = gt_set.alpha
    assert alpha is not None  # the sphere's renders carry their coverage

    def score(seq: Any) -> dict[str, Any]:
        rep = temporal_flicker(seq, gt, alpha, closed=True)
        return {
            "flicker": round(rep.flicker, 5),
            "energy_ratio": round(rep.energy_ratio, 3),
            "psnr_mask_db": _masked_psnr(seq, gt, alpha),
        }

    rows: list[dict[str, Any]] = [
        {"what": "ground truth", **score(gt)},
        {"what": "unrelit input", **score(inputs)},
    ]
    perceptual = load_perceptual_loss()
    for name in models:
        if name == "gaffer-tiny":
            loaded = load_relighting_model(None)
            base: dict[str, Any] = {}
        else:  # the random smoke model: no suggestion of its own, 10 DDIM steps
            loaded = load_relighting_model(None, smoke=True)
            base = {"num_inference_steps": 10}
        pipe = RelightPipeline(loaded.model)
        for mirror in (False, True):
            for shared in (False, True):
                cfg = relight_preset("tiny").diffusion
                cfg = dataclasses.replace(cfg, mirror_average=mirror, shared_noise=shared, **base)
                guide = DiffusionGuide(pipe, cfg, loaded.suggested)
                cond = guide.encode_views(inputs, guide.lighting(env1, orbit.w2c_blender()))
                t0 = time.perf_counter()
                relit = guide.relight_views(cond).float()
                secs = time.perf_counter() - t0
                relit = F.interpolate(
                    relit, size=gt.shape[2:], mode="bilinear", antialias=True, align_corners=False
                )
                row = {
                    "what": f"{name}: 2D relit orbit",
                    "mirror_average": mirror,
                    "noise": "shared" if shared else "per view",
                    "seconds": round(secs, 2),
                    **score(relit),
                }
                rows.append(row)
                common.log(f"  flicker {row}")
        # 3D: Stage 1 alone from the training views' targets, rendered along the orbit
        s1 = relight_preset("tiny", "no-stage2")
        assert s1.stage1 is not None
        s1 = dataclasses.replace(
            s1, stage1=dataclasses.replace(s1.stage1, iterations=FLICKER_STAGE1_ITERS)
        )
        for shared in (False, True):
            cfg = dataclasses.replace(s1.diffusion, shared_noise=shared, **base)
            guide = DiffusionGuide(pipe, cfg, loaded.suggested)
            res = relight_field(
                field, train, env1, guide, dataclasses.replace(s1, diffusion=cfg), perceptual
            )
            with torch.no_grad():
                seq = render_views(res.field, orbit)
            row = {
                "what": f"{name}: Stage 1 field, orbit render",
                "mirror_average": guide.sampling.mirror_average,
                "noise": "shared" if shared else "per view",
                "stage1_iterations": FLICKER_STAGE1_ITERS,
                **score(seq),
            }
            rows.append(row)
            common.log(f"  flicker {row}")
    return {
        "orbit_frames": orbit.num_views,
        "metric": "gaffer_nerf.flicker.temporal_flicker(closed=True, mask=ground-truth alpha)",
        "rows": rows,
    }


def plot(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax0, ax1, ax2) = plt.subplots(1, 3, figsize=(16, 4.8))
    for mode, marker, color in (("fixed", "o", "tab:blue"), ("footprint", "s", "tab:orange")):
        rows = [r for r in payload["fits"] if r["mode"] == mode]
        ax0.plot(
            [r["seconds"] for r in rows],
            [r["test_psnr_db"] for r in rows],
            marker=marker,
            color=color,
            linestyle="none",
            label=f"{mode} grid",
        )
        for r in rows:
            ax0.annotate(
                f"{'x'.join(map(str, r['final_grid']))}\n{r['grid_mib']:.2f} MiB",
                (r["seconds"], r["test_psnr_db"]),
                textcoords="offset points",
                xytext=(5, 3),
                fontsize=7,
            )
    ax0.set_xlabel("fit seconds (300 iterations)")
    ax0.set_ylabel("test PSNR, input lighting (dB)")
    ax0.set_title("Fitting: fixed vs footprint-sized grid")
    ax0.legend(fontsize=8)
    ax0.grid(alpha=0.3)

    rel = payload["relight"]
    phases = rel["full_relight_random_model"]["phase_seconds"]
    ax1.barh(list(phases), list(phases.values()), color="tab:gray")
    for i, v in enumerate(phases.values()):
        ax1.text(v, i, f" {v:.2f} s", va="center", fontsize=8)
    full = rel["full_relight_random_model"]
    ax1.set_xlabel("seconds")
    ax1.set_title(
        f"relight_field, tiny random model\n(stage 1 {full['stage1_iterations']} it, "
        f"stage 2 {full['stage2_iterations']} it, {full['num_inference_steps']} DDIM steps)",
        fontsize=9,
    )
    ax1.invert_yaxis()
    ax1.grid(alpha=0.3, axis="x")

    s1 = rel["stage1_oracle"]
    ax2.plot(
        [r["seconds"] for r in s1], [r["test_psnr_db"] for r in s1], "o-", label="Stage 1, raw"
    )
    ax2.plot(
        [r["seconds"] for r in s1],
        [r["test_psnr_aligned_db"] for r in s1],
        "s--",
        label="Stage 1, aligned in mask",
    )
    for r in s1:
        ax2.annotate(
            f"{r['iterations']} it",
            (r["seconds"], r["test_psnr_db"]),
            textcoords="offset points",
            xytext=(4, -10),
            fontsize=7,
        )
    ax2.axhline(
        rel["input_field_vs_target"]["test_psnr_db"],
        color="tab:red",
        linestyle=":",
        label="input field, not relit",
    )
    ax2.set_xlabel("Stage 1 seconds")
    ax2.set_ylabel("test PSNR, target lighting (dB)")
    ax2.set_title("Stage 1 with oracle relit views")
    ax2.legend(fontsize=8)
    ax2.grid(alpha=0.3)
    fig.suptitle(
        f"gaffer-nerf, tiny presets, sphere scene: {common.short_device(payload['machine'])}"
    )
    fig.tight_layout()
    return fig


def markdown(payload: dict[str, Any]) -> str:
    m = payload["machine"]
    lines = [
        f"Measured {m['date_utc']} on {m['device']}, torch {m['torch']} ({m['torch_threads']} threads); "
        f"load average {m['load_average_start'][0]:.1f} at start, "
        f"{m.get('load_average_end', [float('nan')])[0]:.1f} at end; one run per row.",
        "",
        "| fit | seconds | final grid | grid MiB | test PSNR (dB, input lighting) |",
        "|---|---|---|---|---|",
    ]
    for r in payload["fits"]:
        lines.append(
            f"| {r['label']} | {r['seconds']:.1f} | {'x'.join(map(str, r['final_grid']))} "
            f"| {r['grid_mib']:.3f} | {r['test_psnr_db']:.2f} |"
        )
    rel = payload["relight"]
    full = rel["full_relight_random_model"]
    ph = full["phase_seconds"]
    lines += [
        "",
        "Relighting the fixed-32^3 field, tiny random diffusion model (timings only): "
        + ", ".join(f"{k} {v:.2f} s" for k, v in ph.items())
        + f"; total {full['total_seconds']:.1f} s ({full['stage2_seconds_per_iteration']:.2f} s per "
        "Stage-2 iteration).",
        "",
        "| Stage 1, oracle relit views | seconds | test PSNR (dB, target lighting) | aligned in mask |",
        "|---|---|---|---|",
        f"| input field, not relit | - | {rel['input_field_vs_target']['test_psnr_db']:.2f} "
        f"| {rel['input_field_vs_target']['test_psnr_aligned_db']:.2f} |",
    ]
    for r in rel["stage1_oracle"]:
        lines.append(
            f"| {r['iterations']} iterations | {r['seconds']:.1f} | {r['test_psnr_db']:.2f} "
            f"| {r['test_psnr_aligned_db']:.2f} |"
        )
    fl = payload.get("flicker")
    if fl is not None:
        lines += [
            "",
            f"Multi-view consistency along a closed {fl['orbit_frames']}-frame test orbit under the "
            "target lighting (`gaffer_nerf.flicker`: mean |frame-to-frame change - the ground "
            "truth's| in the mask; energy ratio > 1 moves more than the truth):",
            "",
            "| sequence | mirror average | noise | flicker | energy ratio | masked PSNR (dB) |",
            "|---|---|---|---|---|---|",
        ]
        for r in fl["rows"]:
            mirror = {True: "on", False: "off"}.get(r.get("mirror_average"), "-")
            lines.append(
                f"| {r['what']} | {mirror} | {r.get('noise', '-')} | {r['flicker']:.4f} "
                f"| {r['energy_ratio']:.2f} | {r['psnr_mask_db']:.2f} |"
            )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    import torch

    from gaffer_nerf.testing import orbit_cameras, scene_envmap, sphere_viewset

    threads = common.set_threads(args.threads if args.threads > 0 else 1)
    torch.manual_seed(args.seed)
    meta = common.machine(threads)
    import gaffer_diffusion
    import gaffer_nerf

    meta["gaffer_nerf"] = gaffer_nerf.__version__
    meta["gaffer_diffusion"] = gaffer_diffusion.__version__
    env0, env1 = scene_envmap(0), scene_envmap(1)
    cams, tcams = orbit_cameras(8), orbit_cameras(3, offset_deg=67.0)
    train, train_target = sphere_viewset(cams, env0), sphere_viewset(cams, env1)
    test, test_target = sphere_viewset(tcams, env0), sphere_viewset(tcams, env1)
    common.log(f"bench_nerf: {'quick' if args.quick else 'full'} run, {threads} torch thread(s)")
    t0 = time.perf_counter()
    fits, field = run_fits(args.quick, args.seed, train, test)
    relight = run_relight(args.quick, field, train, train_target, test_target, env1)
    flicker = run_flicker(args.quick, field, train, env0, env1)
    payload: dict[str, Any] = {
        "name": NAME,
        "machine": meta,
        "config": {
            "quick": args.quick,
            "seed": args.seed,
            "scene": "gaffer_nerf.testing sphere, 64x64 px, 8 train / 3 test views, "
            "scene_envmap(0) -> scene_envmap(1)",
            "fit_preset": "tiny",
            "relight_preset": "tiny",
            "footprint_max_resolution": FOOTPRINT_MAX_RESOLUTION,
        },
        "fits": fits,
        "relight": relight,
        "flicker": flicker,
        "wall_seconds": round(time.perf_counter() - t0, 1),
    }
    fig = plot(payload)
    written = common.write_results(NAME, payload, fig, args.update_baseline)
    table = markdown(payload)
    if args.update_baseline:
        common.update_readme(NAME, table)
    print(table)
    base = common.load_baseline(NAME)
    if base is not None and not args.update_baseline:
        print("\nCommitted baseline:\n")
        print(markdown(base))
    common.log("wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
