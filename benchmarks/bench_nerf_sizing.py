"""gaffer-nerf grid sizing: the footprint + iteration-budget rule against fixed grids, at equal time.

Issue 20 item 4. The scene is `bench_nerf.py`'s (the analytic sphere, 64 px, 8 train views, 3 test
views on an offset orbit, input lighting `scene_envmap(0)`); early stopping scores 3 further held-out
views (a third orbit, not the test views). Every fit is `fit_preset("tiny")` (300 iterations of 1024
rays) with early stopping (`EarlyStoppingConfig(eval_every=50, patience=2, min_iterations=150)`), all
in one run, one after the other on the same machine:

- fixed final grids of side 8, 12, 16, 20, 24, 32 and 48 (`sizing.mode="fixed"`): the curve;
- the rule: `sizing.mode="footprint"` (voxel = the finest camera's pixel footprint, capped by the
  iteration budget, `GridSizingConfig.rays_per_cell` = the paper's ratio), `max_resolution` 96 as in
  `bench_nerf.py`, so that the cap is not what decides;
- the footprint alone (`rays_per_cell=None`), the rule before the budget cap.

Per fit: seconds, iterations run, final grid, MiB, test PSNR. The chart puts the rule's pick on the
fixed-grid PSNR-vs-seconds curve.

Run: `python benchmarks/bench_nerf_sizing.py [--quick] [--update-baseline] [--threads N] [--seed S]`
(default 1 thread; about 3 minutes on one free core, `--quick` fewer fixed sides).
"""

import dataclasses
import sys
import time
from collections.abc import Sequence
from typing import Any

import _common as common

NAME = "nerf_sizing"
SIDES = (8, 12, 16, 20, 24, 32, 48)
SIDES_QUICK = (12, 16, 24)
MAX_RESOLUTION = 96


def _fits(quick: bool, seed: int) -> list[dict[str, Any]]:
    from gaffer_nerf import EarlyStoppingConfig, fit_preset, fit_tensorf
    from gaffer_nerf.evaluate import evaluate_field
    from gaffer_nerf.sizing import budget_side
    from gaffer_nerf.testing import orbit_cameras, scene_envmap, sphere_viewset

    env0 = scene_envmap(seed=0)
    train = sphere_viewset(orbit_cameras(8), env0)
    test = sphere_viewset(orbit_cameras(3, offset_deg=67.0), env0)
    heldout = sphere_viewset(orbit_cameras(3, offset_deg=23.0), env0)
    stop = EarlyStoppingConfig(eval_every=50, patience=2, min_iterations=150)
    base = dataclasses.replace(fit_preset("tiny"), seed=seed, early_stopping=stop)
    variants: list[tuple[str, str, Any]] = []
    for side in SIDES_QUICK if quick else SIDES:
        cfg = dataclasses.replace(
            base, final_voxels=side**3, initial_voxels=min(base.initial_voxels, side**3)
        )
        variants.append((f"fixed {side}^3", "fixed", cfg))
    rule = dataclasses.replace(base.sizing, mode="footprint", max_resolution=MAX_RESOLUTION)
    variants.append(("rule", "rule", dataclasses.replace(base, sizing=rule)))
    alone = dataclasses.replace(rule, rays_per_cell=None)
    variants.append(("footprint alone", "footprint", dataclasses.replace(base, sizing=alone)))
    rows = []
    for label, kind, cfg in variants:
        t0 = time.perf_counter()
        res = fit_tensorf(train, cfg, heldout=heldout)
        wall = time.perf_counter() - t0
        rep, _ = evaluate_field(res.field, test, perceptual=None)
        r = res.report
        side = budget_side(cfg) if kind == "rule" else None
        rows.append(
            {
                "label": label,
                "kind": kind,
                "iterations_run": r.iterations_run,
                "seconds": round(r.seconds, 3),
                "wall_seconds": round(wall, 3),
                "final_grid": list(r.final_grid),
                "grid_mib": round(r.grid_bytes / 2**20, 4),
                "test_psnr_db": round(float(rep.mean_raw.psnr), 3),
                "budget_side": None if side is None else round(side, 2),
            }
        )
        common.log(
            f"  {label:<16} {r.seconds:6.1f} s  {r.iterations_run:>3} it  grid "
            f"{'x'.join(map(str, r.final_grid)):<9} {r.grid_bytes / 2**20:6.3f} MiB  "
            f"test PSNR {rep.mean_raw.psnr:.2f} dB"
        )
    return rows


def plot(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    fixed = sorted((r for r in payload["fits"] if r["kind"] == "fixed"), key=lambda r: r["seconds"])
    ax.plot(
        [r["seconds"] for r in fixed],
        [r["test_psnr_db"] for r in fixed],
        "o-",
        color="tab:blue",
        label="fixed grid (side^3)",
    )
    for r in fixed:
        ax.annotate(
            r["label"].replace("fixed ", ""),
            (r["seconds"], r["test_psnr_db"]),
            textcoords="offset points",
            xytext=(4, -11),
            fontsize=8,
        )
    for kind, marker, color, name in (
        ("rule", "*", "tab:red", "rule: footprint + iteration budget"),
        ("footprint", "s", "tab:orange", "footprint alone (before)"),
    ):
        for r in (r for r in payload["fits"] if r["kind"] == kind):
            ax.plot(r["seconds"], r["test_psnr_db"], marker, color=color, markersize=13, label=name)
            ax.annotate(
                "x".join(map(str, r["final_grid"])),
                (r["seconds"], r["test_psnr_db"]),
                textcoords="offset points",
                xytext=(8, 4),
                fontsize=8,
                color=color,
            )
    ax.set_xlabel("fit seconds (300 iterations max, early stopping)")
    ax.set_ylabel("test PSNR (dB, input lighting)")
    ax.set_title(f"Grid sizing on the sphere, one run ({common.short_device(payload['machine'])})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    return fig


def main(argv: Sequence[str] | None = None) -> int:
    args = common.parse_args(__doc__.split("\n")[0], argv)
    threads = common.set_threads(args.threads or 1)
    meta = common.machine(threads)
    import gaffer_nerf

    meta["gaffer_nerf"] = gaffer_nerf.__version__
    rows = _fits(args.quick, args.seed)
    payload = {
        "name": NAME,
        "machine": meta,
        "config": {
            "quick": args.quick,
            "seed": args.seed,
            "scene": "gaffer_nerf.testing sphere, 64 px, 8 train / 3 test / 3 early-stopping views",
            "fit_preset": "tiny (300 iterations of 1024 rays)",
            "early_stopping": "eval_every 50, patience 2, min_iterations 150",
            "footprint_max_resolution": MAX_RESOLUTION,
        },
        "fits": rows,
    }
    fixed = [r for r in rows if r["kind"] == "fixed"]
    rule = next(r for r in rows if r["kind"] == "rule")
    best = max(fixed, key=lambda r: r["test_psnr_db"])
    payload["summary"] = {
        "rule_psnr_db": rule["test_psnr_db"],
        "rule_seconds": rule["seconds"],
        "rule_grid": rule["final_grid"],
        "best_fixed": best["label"],
        "best_fixed_psnr_db": best["test_psnr_db"],
        "best_fixed_seconds": best["seconds"],
        "rule_minus_best_fixed_db": round(rule["test_psnr_db"] - best["test_psnr_db"], 3),
    }
    for path in common.write_results(NAME, payload, plot(payload), args.update_baseline):
        common.log(f"wrote {path}")
    s = payload["summary"]
    print(
        f"rule {'x'.join(map(str, s['rule_grid']))}: {s['rule_psnr_db']:.2f} dB in "
        f"{s['rule_seconds']:.1f} s; best fixed {s['best_fixed']}: {s['best_fixed_psnr_db']:.2f} dB "
        f"in {s['best_fixed_seconds']:.1f} s ({s['rule_minus_best_fixed_db']:+.2f} dB)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
