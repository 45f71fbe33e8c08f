"""Shared plumbing of the validation-split sweeps that choose `relight_preset("tiny")`'s settings.

Issue 20. `bench_nerf_stage2_val.py` (Stage 2's settings), `bench_nerf_stage1_val.py` (Stage 1's
targets) and `bench_nerf_noise_val.py` (shared vs per-view noise) run the same experiment shape on
the VALIDATION split of `bench_nerf_real.py` (3 unseen procedural objects of `--seed 42`, `city` ->
`forest` / `studio`, disjoint from the test split in objects and target lightings): one fit per
object, then per (object, target) pair one relighting per setting, each scored on the 5 test views
under the target. This module holds what they share: loading the split, the model and the metrics
(`prepare`), the pairs (`pairs`), the scores (`score`), the means over pairs (`means`), the table
(`table`), a PSNR-vs-ST-LPIPS chart (`scatter`) and the command line (`main`). Each script keeps its
own settings, its per-pair loop and its selection rule, fixed in its docstring before its run.

Not a benchmark itself (`nox -s bench` runs only `bench_*.py`).
"""

import dataclasses
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import _common as common
import bench_nerf_real as real
import numpy as np

KEYS = (
    "psnr_object_db",
    "psnr_object_aligned_db",
    "ssim_object",
    "stlpips_crop",
    "psnr_full_frame_db",
    "seconds",
)
"""The per-setting numbers every sweep records (seconds: of the phase the sweep varies)."""


@dataclasses.dataclass
class Sweep:
    """What one validation sweep loads once: the split's objects, the fit and relight configs (the tiny
    presets with the benchmark's iteration counts and seed), the model and the metrics."""

    quick: bool
    seed: int
    split: real.Split
    root: Path
    folders: list[Path]
    targets: tuple[str, ...]
    fit_cfg: Any
    relight_cfg: Any
    loaded: Any
    pipeline: Any
    perceptual_loss: Any
    metric: Any

    def guide(self, **diffusion: Any) -> Any:
        """A `DiffusionGuide` of the shipped model with the preset's sampling and `diffusion` overrides."""
        from gaffer_nerf.guidance import DiffusionGuide

        cfg = dataclasses.replace(self.relight_cfg.diffusion, **diffusion)
        return DiffusionGuide(self.pipeline, cfg, self.loaded.suggested)

    def config(self, **extra: Any) -> dict[str, Any]:
        """The result's `config`: the split, the counts and the model, plus the sweep's own `extra`."""
        r = self.relight_cfg
        return {
            "quick": self.quick,
            "seed": self.seed,
            "split": self.split.name,
            "objects": [f.name for f in self.folders],
            "objects_from": f"gaffer-data recipe --procedural {real.NUM_OBJECTS} --seed "
            f"{self.split.object_seed}",
            "input_lighting": real.INPUT_HDRI,
            "target_lightings": list(self.targets),
            "target_lightings_are": self.split.targets_are,
            "fit_iterations": self.fit_cfg.iterations,
            "stage1_iterations": r.stage1.iterations,
            **extra,
            "model": self.loaded.name,
        }


@dataclasses.dataclass
class Pair:
    """One (object, target lighting) pair: the input-lighting scene and its fit, the target's test
    views (the ground truth) and its environment map."""

    folder: Path
    target: str
    scene: Any
    fit: Any
    ground_truth: Any
    envmap: Any


def prepare(quick: bool, seed: int, only: Sequence[str] | None = None) -> Sweep:
    """Render (once) and load the validation split, the shipped model and the metrics.

    `only`: object folder names to keep (a part of a sweep split over processes).
    """
    from gaffer_diffusion import RelightPipeline, RuntimeConfig
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual
    from gaffer_nerf import load_perceptual_loss
    from gaffer_nerf.guidance.model import load_relighting_model

    split = real.VALIDATION
    n_objects = 1 if quick else real.NUM_OBJECTS
    root = real.renders(n_objects, split)
    folders = sorted(
        p for p in (root / "objects").iterdir() if (p / "transforms_test.json").is_file()
    )[:n_objects]
    if only:
        folders = [f for f in folders if f.name in only]
        if len(folders) != len(only):
            raise RuntimeError(f"--objects {list(only)}: not all among the rendered objects")
    fit_cfg, rcfg = real.configs(quick, seed)
    loaded = load_relighting_model(None)  # what `gaffer-nerf relight` does without --checkpoint
    try:
        metric: Any = load_perceptual()
    except MetricUnavailableError as exc:
        common.log(f"  ST-LPIPS unavailable ({exc}); scored without it")
        metric = None
    return Sweep(
        quick=quick,
        seed=seed,
        split=split,
        root=root,
        folders=folders,
        targets=split.targets[:1] if quick else split.targets,
        fit_cfg=fit_cfg,
        relight_cfg=rcfg,
        loaded=loaded,
        pipeline=RelightPipeline(loaded.model, RuntimeConfig(device="cpu", dtype="float32")),
        perceptual_loss=load_perceptual_loss(),
        metric=metric,
    )


def pairs(sweep: Sweep) -> Iterator[Pair]:
    """Every (object, target) pair, each object fitted once under the input lighting."""
    from gaffer_nerf import fit_tensorf, read_gaffer_data_object
    from gaffer_nerf.data import load_lighting_envmap

    for folder in sweep.folders:
        idx = real.lighting_indices(read_gaffer_data_object(folder))
        scene = read_gaffer_data_object(folder, lighting_index=idx[real.INPUT_HDRI])
        fit = fit_tensorf(scene.train, sweep.fit_cfg)
        for target in sweep.targets:
            li = idx[target]
            gt = read_gaffer_data_object(folder, lighting_index=li).test
            if gt is None:
                raise RuntimeError(f"{folder} has no test views")
            env = load_lighting_envmap(scene.lighting(li), sweep.root.parent / "held" / "envmaps")
            yield Pair(folder, target, scene, fit, gt, env)


def score(sweep: Sweep, field: Any, ground_truth: Any, seconds: float) -> dict[str, Any]:
    """`field` scored on the test views (`bench_nerf_real.scores`) with the phase's seconds."""
    from gaffer_nerf import evaluate_field

    rep, _ = evaluate_field(field, ground_truth, perceptual=sweep.metric)
    return {**real.scores(rep), "seconds": round(seconds, 3)}


def log_pair(row: dict[str, Any]) -> None:
    common.log(
        f"  {row['object']} -> {row['target']}: "
        + ", ".join(
            f"{k} {v['psnr_object_db']:.2f}/{v['stlpips_crop']}" for k, v in row["rows"].items()
        )
    )


def higher_psnr(row: dict[str, Any], ref: dict[str, Any]) -> bool:
    """The `wins` of `means` most sweeps count: a higher object PSNR (raw) than the reference's."""
    return row["psnr_object_db"] > ref["psnr_object_db"]


def means(
    pairs: Sequence[dict[str, Any]],
    reference: str,
    wins_key: str,
    wins: Callable[[dict, dict], bool],
) -> dict[str, dict[str, Any]]:
    """Per setting: the mean of each of `KEYS` over the pairs, and `wins_key`: on how many pairs
    `wins(row, reference_row)` holds."""
    out: dict[str, dict[str, Any]] = {}
    for name in pairs[0]["rows"]:
        vals: dict[str, Any] = {}
        for key in KEYS:
            xs = [p["rows"][name][key] for p in pairs if p["rows"][name].get(key) is not None]
            vals[key] = round(float(np.mean(xs)), 4) if xs else None
        vals[wins_key] = sum(wins(p["rows"][name], p["rows"][reference]) for p in pairs)
        out[name] = vals
    return out


def table(
    means: dict[str, dict[str, Any]],
    pairs: int,
    first: str,
    seconds: str,
    wins_key: str,
    wins: str,
    *,
    lpips_digits: int = 4,
) -> str:
    """The Markdown table of `means` (one row per setting)."""
    lines = [
        f"| {first} | object PSNR raw | aligned | SSIM | ST-LPIPS | full frame | {seconds} | "
        f"{wins} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, v in means.items():
        lp = "-" if v["stlpips_crop"] is None else f"{v['stlpips_crop']:.{lpips_digits}f}"
        lines.append(
            f"| {name} | {v['psnr_object_db']:.2f} | {v['psnr_object_aligned_db']:.2f} | "
            f"{v['ssim_object']:.3f} | {lp} | {v['psnr_full_frame_db']:.2f} | "
            f"{v['seconds']:.1f} | {v[wins_key]}/{pairs} |"
        )
    return "\n".join(lines)


def report(
    payload: dict[str, Any], first: str, seconds: str, wins_key: str, wins: str, **kw: Any
) -> str:
    """`table` of the payload's means and the line naming the setting the rule chose."""
    means = payload["summary"]["means"]
    return "\n".join(
        [
            table(means, len(payload["pairs"]), first, seconds, wins_key, wins, **kw),
            "",
            f"Chosen by the fixed rule: **{payload['summary']['chosen']}**.",
        ]
    )


def scatter(payload: dict[str, Any], what: str, floor_db: float | None = None) -> Any:
    """Object PSNR against ST-LPIPS, one point per setting (the chosen one red, unrelit grey)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = payload["summary"]
    chosen = summary["chosen"]
    fig, ax = plt.subplots(figsize=(7, 5))
    for name, m in summary["means"].items():
        if m["stlpips_crop"] is None:
            continue
        colour = "tab:red" if name == chosen else "#888888" if name == "unrelit" else "tab:blue"
        ax.scatter(m["stlpips_crop"], m["psnr_object_db"], color=colour)
        ax.annotate(
            name,
            (m["stlpips_crop"], m["psnr_object_db"]),
            fontsize=8,
            xytext=(3, 3),
            textcoords="offset points",
        )
    floor = ""
    if floor_db is not None:
        ax.axhline(floor_db, color="tab:red", lw=0.8, ls="--")
        floor = " (dashed: the PSNR floor of the rule)"
    ax.set_xlabel("ST-LPIPS on the object crop (shift-tolerant AlexNet; lower is better)")
    ax.set_ylabel("object-mask PSNR, raw (dB)")
    ax.grid(alpha=0.3)
    cfg = payload["config"]
    ax.set_title(
        f"{what} on the validation split ({len(payload['pairs'])} pairs: "
        f"{', '.join(cfg['objects'])} x {', '.join(cfg['target_lightings'])})\n"
        f"chosen: {chosen}{floor}; {common.short_device(payload['machine'])}",
        fontsize=8,
    )
    fig.tight_layout()
    return fig


def main(
    name: str,
    doc: str,
    run: Callable[[bool, int], dict[str, Any]],
    summarise: Callable[[dict[str, Any]], dict[str, Any]],
    plot: Callable[[dict[str, Any]], Any],
    markdown: Callable[[dict[str, Any]], str],
    argv: Sequence[str] | None = None,
) -> int:
    """The command line of a sweep: run, summarise, write the results (and the baseline), print."""
    args = common.parse_args(doc.split("\n")[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    t0 = time.perf_counter()
    payload = {"name": name, "machine": meta, **run(args.quick, args.seed)}
    payload["summary"] = summarise(payload)
    payload["seconds"] = {"total_wall": round(time.perf_counter() - t0, 1)}
    for path in common.write_results(name, payload, plot(payload), args.update_baseline):
        common.log(f"wrote {path}")
    print(markdown(payload))
    return 0
