"""gaffer-nerf grid sizing: the footprint + iteration-budget rule against fixed grids, at equal time.

The scene is `bench_nerf.py`'s (the analytic sphere, 64 px, 8 train views, 3 test
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

`--real test|validation`: the same comparison on the gaffer-data Cycles renders of
`bench_nerf_real.py` (3 unseen procedural objects per split, 64 px, input lighting city; rendered
once by that benchmark or `nerf_sweep.py` and reused here). Per object, the 20 train views
are split into 17 fitted views and 3 early-stopping views (train indices 3, 10, 17); fit quality is
the object-mask PSNR on the object's 5 held-out test views under the input lighting. Same fixed sides,
same 300-iteration budget and early stopping; the footprint-alone fit is skipped. Results go to
`nerf_sizing_real` (test split) or `nerf_sizing_real_val` (validation split, where any change to the
rule is chosen; the test split is run once after).
"""

import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import _common as common

NAME = "nerf_sizing"
REAL_NAMES = {
    "test": "nerf_sizing_real",
    "validation": "nerf_sizing_real_val",
    "validation-b": "nerf_sizing_real_val_b",
}
EARLY_STOP_VIEWS = (3, 10, 17)
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


def real_object_folders(split: Any, quick: bool) -> list[Path]:
    """The split's rendered objects (rendering them once if needed); one when `quick`."""
    import bench_nerf_real as real

    root = real.renders(real.NUM_OBJECTS, split)
    return sorted(
        p for p in (root / "objects").iterdir() if (p / "transforms_test.json").is_file()
    )[: 1 if quick else real.NUM_OBJECTS]


def input_lighting_views(folder: Path) -> tuple[Any, Any, Any]:
    """An object under the input lighting: the scene (its test views scored), the train views fitted,
    and the train views `EARLY_STOP_VIEWS` held out for early stopping."""
    import bench_nerf_real as real

    from gaffer_nerf import read_gaffer_data_object

    probe = read_gaffer_data_object(folder)
    idx = real.lighting_indices(probe)
    scene = read_gaffer_data_object(folder, lighting_index=idx[real.INPUT_HDRI])
    assert scene.test is not None
    n = scene.train.num_views
    fitted = scene.train.select([i for i in range(n) if i not in EARLY_STOP_VIEWS])
    heldout = scene.train.select(list(EARLY_STOP_VIEWS))
    return scene, fitted, heldout


def _real_fits(quick: bool, seed: int, split_name: str) -> list[dict[str, Any]]:
    import bench_nerf_real as real

    from gaffer_nerf import EarlyStoppingConfig, fit_preset, fit_tensorf
    from gaffer_nerf.evaluate import evaluate_field
    from gaffer_nerf.sizing import budget_side

    folders = real_object_folders(real.SPLITS[split_name], quick)
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
    rows = []
    warm = True
    for folder in folders:
        scene, fitted, heldout = input_lighting_views(folder)
        if warm:  # a short untimed fit first, so that the first timed fit pays no start-up cost
            fit_tensorf(fitted, dataclasses.replace(base, iterations=60, early_stopping=None))
            warm = False
        for label, kind, cfg in variants:
            t0 = time.perf_counter()
            res = fit_tensorf(fitted, cfg, heldout=heldout)
            wall = time.perf_counter() - t0
            rep, _ = evaluate_field(res.field, scene.test, perceptual=None)
            r = res.report
            side = budget_side(cfg) if kind == "rule" else None
            rows.append(
                {
                    "object": folder.name,
                    "label": label,
                    "kind": kind,
                    "iterations_run": r.iterations_run,
                    "seconds": round(r.seconds, 3),
                    "wall_seconds": round(wall, 3),
                    "final_grid": list(r.final_grid),
                    "grid_mib": round(r.grid_bytes / 2**20, 4),
                    "test_psnr_object_db": round(float(rep.mean_object_raw.psnr), 3),
                    "test_psnr_db": round(float(rep.mean_raw.psnr), 3),
                    "budget_side": None if side is None else round(side, 2),
                }
            )
            common.log(
                f"  {folder.name} {label:<10} {r.seconds:6.1f} s  {r.iterations_run:>3} it  grid "
                f"{'x'.join(map(str, r.final_grid)):<9} object PSNR "
                f"{rep.mean_object_raw.psnr:.2f} dB (full frame {rep.mean_raw.psnr:.2f})"
            )
    return rows


def _real_means(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per label: mean object PSNR, mean seconds over the objects (and the rule's grids)."""
    out = []
    for label in dict.fromkeys(r["label"] for r in rows):
        rs = [r for r in rows if r["label"] == label]
        out.append(
            {
                "label": label,
                "kind": rs[0]["kind"],
                "objects": len(rs),
                "test_psnr_object_db": round(
                    sum(r["test_psnr_object_db"] for r in rs) / len(rs), 3
                ),
                "test_psnr_db": round(sum(r["test_psnr_db"] for r in rs) / len(rs), 3),
                "seconds": round(sum(r["seconds"] for r in rs) / len(rs), 3),
                "iterations_run": round(sum(r["iterations_run"] for r in rs) / len(rs), 1),
                "final_grids": [r["final_grid"] for r in rs],
            }
        )
    return out


def _real_summary(rows: list[dict[str, Any]], means: list[dict[str, Any]]) -> dict[str, Any]:
    key = "test_psnr_object_db"
    fixed = [m for m in means if m["kind"] == "fixed"]
    rule = next(m for m in means if m["kind"] == "rule")
    best = max(fixed, key=lambda m: m[key])
    in_time = [m for m in fixed if m["seconds"] <= rule["seconds"]]
    best_in_time = max(in_time, key=lambda m: m[key]) if in_time else None
    per_object = {}
    for obj in dict.fromkeys(r["object"] for r in rows):
        rs = [r for r in rows if r["object"] == obj]
        ru = next(r for r in rs if r["kind"] == "rule")
        bf = max((r for r in rs if r["kind"] == "fixed"), key=lambda r: r[key])
        per_object[obj] = {
            "rule_grid": ru["final_grid"],
            "rule_psnr_object_db": ru[key],
            "rule_seconds": ru["seconds"],
            "best_fixed": bf["label"],
            "best_fixed_psnr_object_db": bf[key],
            "best_fixed_seconds": bf["seconds"],
            "rule_minus_best_fixed_db": round(ru[key] - bf[key], 3),
        }
    return {
        "metric": "object-mask PSNR on the test views, input lighting (mean over objects)",
        "rule_psnr_object_db": rule[key],
        "rule_seconds": rule["seconds"],
        "rule_grids": rule["final_grids"],
        "best_fixed": best["label"],
        "best_fixed_psnr_object_db": best[key],
        "best_fixed_seconds": best["seconds"],
        "rule_minus_best_fixed_db": round(rule[key] - best[key], 3),
        "best_fixed_within_rule_time": None if best_in_time is None else best_in_time["label"],
        "rule_minus_best_fixed_within_rule_time_db": None
        if best_in_time is None
        else round(rule[key] - best_in_time[key], 3),
        "per_object": per_object,
    }


def _side(r: dict[str, Any]) -> float:
    g = r.get("final_grid") or r["final_grids"][0]
    grids = r.get("final_grids") or [g]
    return sum((a * b * c) ** (1 / 3) for a, b, c in grids) / len(grids)


def plot_real(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    objects = list(dict.fromkeys(r["object"] for r in payload["fits"]))
    panels = [("mean over objects", payload["means"])] + [
        (o, [r for r in payload["fits"] if r["object"] == o]) for o in objects
    ]
    fig, axes = plt.subplots(
        2, len(panels), figsize=(4.2 * len(panels), 6.4), squeeze=False, sharex=True
    )
    for col, (title, rs) in enumerate(panels):
        fixed = sorted((r for r in rs if r["kind"] == "fixed"), key=_side)
        rule = [r for r in rs if r["kind"] == "rule"]
        for row, key, ylabel in (
            (0, "test_psnr_object_db", "test object PSNR (dB, input lighting)"),
            (1, "seconds", "fit seconds (300 it max, early stopping)"),
        ):
            ax = axes[row][col]
            ax.plot(
                [_side(r) for r in fixed],
                [r[key] for r in fixed],
                "o-",
                color="tab:blue",
                label="fixed grid (side^3)",
            )
            for r in rule:
                ax.plot(
                    _side(r),
                    r[key],
                    "*",
                    color="tab:red",
                    markersize=14,
                    label="rule's pick (footprint + iteration budget)",
                )
                if row == 0 and "final_grid" in r:
                    ax.annotate(
                        "x".join(map(str, r["final_grid"])),
                        (_side(r), r[key]),
                        textcoords="offset points",
                        xytext=(8, -12),
                        fontsize=8,
                        color="tab:red",
                    )
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(ylabel, fontsize=9)
            if row == 0:
                ax.set_title(title, fontsize=10)
            else:
                ax.set_xlabel("final grid side (cube root of voxels)")
    axes[0][0].legend(fontsize=8, loc="lower right")
    fig.suptitle(
        f"Grid sizing on gaffer-data renders ({payload['config']['split']} split), one run "
        f"({common.short_device(payload['machine'])})",
        fontsize=11,
    )
    fig.tight_layout()
    return fig


def markdown_real(payload: dict[str, Any]) -> str:
    """The README block: mean and per-object object PSNR / seconds per grid, and the verdict."""
    m, s = payload["machine"], payload["summary"]
    objects = list(dict.fromkeys(r["object"] for r in payload["fits"]))
    by = {(r["object"], r["label"]): r for r in payload["fits"]}
    head = "| grid | " + " | ".join(f"{o} dB / s" for o in objects) + " | mean dB | mean s |"
    lines = [
        f"Measured {m['date_utc']}, {payload['config']['split']} split ({common.short_device(m)}; "
        f"load {m['load_average_end'][0]} at end). "
        "Object-mask PSNR on the 5 test views under the input lighting; 300 iterations of 1024 "
        "rays, early stopping on 3 train views.",
        "",
        head,
        "|---" * (len(objects) + 3) + "|",
    ]
    for mean in payload["means"]:
        name = mean["label"].replace("fixed ", "")
        if mean["kind"] == "rule":
            name = "**rule's pick**"
        cells = []
        for o in objects:
            r = by[(o, mean["label"])]
            grid = f" ({'x'.join(map(str, r['final_grid']))})" if mean["kind"] == "rule" else ""
            cells.append(f"{r['test_psnr_object_db']:.2f} / {r['seconds']:.1f}{grid}")
        lines.append(
            f"| {name} | {' | '.join(cells)} | {mean['test_psnr_object_db']:.2f} | "
            f"{mean['seconds']:.1f} |"
        )
    lines += [
        "",
        f"Rule minus best fixed grid ({s['best_fixed']}, {s['best_fixed_seconds']:.1f} s): "
        f"{s['rule_minus_best_fixed_db']:+.2f} dB in {s['rule_seconds']:.1f} s; best fixed grid "
        f"no slower than the rule: {s['best_fixed_within_rule_time']} "
        f"({s['rule_minus_best_fixed_within_rule_time_db']:+.2f} dB for the rule)."
        if s["best_fixed_within_rule_time"] is not None
        else f"Rule minus best fixed grid ({s['best_fixed']}, {s['best_fixed_seconds']:.1f} s): "
        f"{s['rule_minus_best_fixed_db']:+.2f} dB in {s['rule_seconds']:.1f} s; no fixed grid ran "
        "in less time than the rule.",
    ]
    return "\n".join(lines)


def main_real(split: str, args: Any) -> int:
    threads = common.set_threads(args.threads or 1)
    meta = common.machine(threads)
    import gaffer_nerf

    meta["gaffer_nerf"] = gaffer_nerf.__version__
    rows = _real_fits(args.quick, args.seed, split)
    means = _real_means(rows)
    name = REAL_NAMES[split] + ("-quick" if args.quick else "")
    payload: dict[str, Any] = {
        "name": name,
        "machine": meta,
        "config": {
            "split": split,
            "quick": args.quick,
            "seed": args.seed,
            "scene": "bench_nerf_real renders (gaffer-data Cycles, 64 px, input lighting city): "
            f"17 fitted train views, early stopping on train views {list(EARLY_STOP_VIEWS)}, "
            "scored on the 5 test views",
            "fit_preset": "tiny (300 iterations of 1024 rays)",
            "early_stopping": "eval_every 50, patience 2, min_iterations 150",
            "footprint_max_resolution": MAX_RESOLUTION,
        },
        "fits": rows,
        "means": means,
    }
    payload["summary"] = _real_summary(rows, means)
    for path in common.write_results(name, payload, plot_real(payload), args.update_baseline):
        common.log(f"wrote {path}")
    if args.update_baseline and not args.quick:
        common.update_readme(name, markdown_real(payload))
    for m in means:
        print(
            f"{m['label']:<10} object PSNR {m['test_psnr_object_db']:6.2f} dB  "
            f"{m['seconds']:6.1f} s  grids {m['final_grids']}"
        )
    s = payload["summary"]
    print(
        f"rule: {s['rule_psnr_object_db']:.2f} dB in {s['rule_seconds']:.1f} s; best fixed "
        f"{s['best_fixed']}: {s['best_fixed_psnr_object_db']:.2f} dB in "
        f"{s['best_fixed_seconds']:.1f} s ({s['rule_minus_best_fixed_db']:+.2f} dB); best fixed "
        f"within the rule's time: {s['best_fixed_within_rule_time']} "
        f"({s['rule_minus_best_fixed_within_rule_time_db']})"
    )
    return 0


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
    argv = list(sys.argv[1:] if argv is None else argv)
    split = None
    if "--real" in argv:
        i = argv.index("--real")
        split = argv[i + 1] if i + 1 < len(argv) else ""
        if split not in REAL_NAMES:
            print("--real takes 'test', 'validation' or 'validation-b'", file=sys.stderr)
            return 2
        del argv[i : i + 2]
    args = common.parse_args(__doc__.split("\n")[0], argv)
    if split is not None:
        return main_real(split, args)
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
