"""The validation sweeps that chose `fit_preset("tiny")`'s and `relight_preset("tiny")`'s settings.

One runner for the five one-off sweeps, each a row of `SWEEPS`: the preset setting it decides, its
candidates, the rule that picks one (fixed before its run) and the choice the preset ships. Every
sweep runs on the VALIDATION splits of `bench_nerf_real.py`, never its test split: three unseen
procedural objects (`gaffer-data recipe --procedural 3 --seed 42`) rendered as in the test benchmark
(64 px, 20 train + 5 test views) under `city` (input) and `forest` / `studio` (gaffer-tiny's validation
HDRIs); the density-L1 sweep adds three more objects (`--seed 43`, input lighting only).

- `stage2`: Stage 2's settings (learning rates, t* range and schedule, loss weights, step count),
  beside Stage 1 only and SDS only. Stage 2 with the paper's shape cost about 0.9 dB after Stage 1 on
  the test split.
- `stage1`: Stage 1's targets: the relit views as the model made them, or their change of shading
  transferred onto the input views over a box of r view pixels (`gaffer_nerf.relight.detail`), since
  gaffer-tiny's relit views blur the object's texture and Stage 1 baked that into the field.
- `noise`: one initial noise shared by every relit training view, or one per view (multi-view
  consistency; on the sphere scene it cut the relit orbit's flicker by 31% for 0.85 dB).
- `stage2-detail`: Stage 2's guidance target: the model's denoised view, or the render times the
  model's change of shading (only the light corrected).
- `l1`: the fit's density L1 at the footprint sizing rule's grids; TensoRF's 8e-5 held a small
  object's density at zero on the tiny grids (the L1 acts on each factor's mean).

Per (object, target) pair the relighting sweeps fit once, then relight under each candidate with the
same seed, and score on the 5 test views: object-mask PSNR raw and aligned, SSIM, ST-LPIPS
(shift-tolerant AlexNet, not standard LPIPS) on the object crop, full-frame PSNR and the seconds of
the phase the sweep varies. The L1 sweep fits each object per candidate and fit seed (0, 1) and
scores under the input lighting.

Every result file records the rule and the choice (`choice`); `check` recomputes each committed
file's means from its per-pair (per-fit) rows, applies the rule to them and compares with the
recorded choice, the rule text and the value the preset ships, without rerunning anything:

    python benchmarks/nerf_sweep.py list
    python benchmarks/nerf_sweep.py check [SWEEP ...]
    python benchmarks/nerf_sweep.py run SWEEP [--quick] [--update-baseline] [--threads N]
    python benchmarks/nerf_sweep.py run SWEEP --objects procedural_000   # a part, on a busy machine
    python benchmarks/nerf_sweep.py merge SWEEP results/runs/<name>-part-*.json [--update-baseline]
    python benchmarks/nerf_sweep.py record [SWEEP ...]   # rewrite the summary and choice of the
                                                         # committed files from their own rows

A full run renders the validation split once (about 5 minutes), then takes 1-2.6 CPU-minutes per
pair and candidate set (`stage2`: about 20 minutes per object with 1 thread; `l1`: about 8 minutes).
Not a benchmark itself (`nox -s bench` runs only `bench_*.py`).
"""

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import _common as common
import bench_nerf_real as real
import numpy as np

Means = dict[str, dict[str, Any]]
"""Per candidate (and reference row): the mean of each score over the pairs or fits."""

KEYS = (
    "psnr_object_db",
    "psnr_object_aligned_db",
    "ssim_object",
    "stlpips_crop",
    "psnr_full_frame_db",
    "seconds",
)
"""The per-setting numbers every relighting sweep records (seconds: of the phase the sweep varies)."""


# --------------------------------------------------------------------------------------------------
# The shared experiment of the relighting sweeps
# --------------------------------------------------------------------------------------------------
@dataclass
class Validation:
    """What a relighting sweep loads once: the split's objects, the fit and relight configs (the tiny
    presets with the benchmark's iteration counts and seed), the model and the metrics."""

    quick: bool
    seed: int
    split: Any
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


@dataclass
class Pair:
    """One (object, target lighting) pair: the input-lighting scene and its fit, the target's test
    views (the ground truth) and its environment map."""

    folder: Path
    target: str
    scene: Any
    fit: Any
    ground_truth: Any
    envmap: Any


def prepare(quick: bool, seed: int, only: Sequence[str] | None = None) -> Validation:
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
            raise SystemExit(f"--objects {list(only)}: not all among the rendered objects")
    fit_cfg, rcfg = real.configs(quick, seed)
    loaded = load_relighting_model(None)  # what `gaffer-nerf relight` does without --checkpoint
    try:
        metric: Any = load_perceptual()
    except MetricUnavailableError as exc:
        common.log(f"  ST-LPIPS unavailable ({exc}); scored without it")
        metric = None
    return Validation(
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


def pairs(split: Validation) -> Iterator[Pair]:
    """Every (object, target) pair, each object fitted once under the input lighting."""
    from gaffer_nerf import fit_tensorf, read_gaffer_data_object
    from gaffer_nerf.data import load_lighting_envmap

    for folder in split.folders:
        idx = real.lighting_indices(read_gaffer_data_object(folder))
        scene = read_gaffer_data_object(folder, lighting_index=idx[real.INPUT_HDRI])
        fit = fit_tensorf(scene.train, split.fit_cfg)
        for target in split.targets:
            li = idx[target]
            gt = read_gaffer_data_object(folder, lighting_index=li).test
            if gt is None:
                raise RuntimeError(f"{folder} has no test views")
            env = load_lighting_envmap(scene.lighting(li), split.root.parent / "held" / "envmaps")
            yield Pair(folder, target, scene, fit, gt, env)


def score(split: Validation, field: Any, ground_truth: Any, seconds: float) -> dict[str, Any]:
    """`field` scored on the test views (`bench_nerf_real.scores`) with the phase's seconds."""
    from gaffer_nerf import evaluate_field

    rep, _ = evaluate_field(field, ground_truth, perceptual=split.metric)
    return {**real.scores(rep), "seconds": round(seconds, 3)}


def _stage_seconds(stage: Any) -> float:
    return stage.seconds if stage else 0.0


def relight_pairs(
    split: Validation,
    names: Sequence[str],
    references: Callable[[Validation, Pair, dict[str, Any]], dict[str, Any]],
    candidate: Callable[[Validation, Pair, str, dict[str, Any]], dict[str, Any]],
) -> list[dict[str, Any]]:
    """Per pair: the unrelit field, the sweep's reference rows (`references` returns what the
    candidates share, e.g. one set of relit views), then each candidate."""
    rows: list[dict[str, Any]] = []
    for pair in pairs(split):
        row: dict[str, Any] = {"object": pair.folder.name, "target": pair.target, "rows": {}}
        row["rows"]["unrelit"] = score(split, pair.fit.field, pair.ground_truth, 0.0)
        shared = references(split, pair, row["rows"])
        for name in names:
            row["rows"][name] = candidate(split, pair, name, shared)
        rows.append(row)
        common.log(
            f"  {row['object']} -> {row['target']}: "
            + ", ".join(
                f"{k} {v['psnr_object_db']:.2f}/{v['stlpips_crop']}" for k, v in row["rows"].items()
            )
        )
    return rows


def pair_means(
    rows: Sequence[dict[str, Any]],
    reference: str,
    wins_key: str,
    wins: Callable[[dict, dict], bool],
) -> Means:
    """Per setting: the mean of each of `KEYS` over the pairs, and `wins_key`: on how many pairs
    `wins(row, reference_row)` holds."""
    out: Means = {}
    for name in rows[0]["rows"]:
        vals: dict[str, Any] = {}
        for key in KEYS:
            xs = [p["rows"][name][key] for p in rows if p["rows"][name].get(key) is not None]
            vals[key] = round(float(np.mean(xs)), 4) if xs else None
        vals[wins_key] = sum(wins(p["rows"][name], p["rows"][reference]) for p in rows)
        out[name] = vals
    return out


def higher_psnr(row: dict[str, Any], ref: dict[str, Any]) -> bool:
    """A higher object PSNR (raw) than the reference row's."""
    return row["psnr_object_db"] > ref["psnr_object_db"]


def lower_stlpips(row: dict[str, Any], ref: dict[str, Any]) -> bool:
    """A lower ST-LPIPS than the reference row's (a missing metric counts as 0)."""
    return (row["stlpips_crop"] or 0) < (ref["stlpips_crop"] or 0)


def _lpips_no_worse(m: dict[str, Any], ref: dict[str, Any]) -> bool:
    """`m`'s mean ST-LPIPS is no worse than `ref`'s (always, when the reference has none)."""
    return ref["stlpips_crop"] is None or (
        m["stlpips_crop"] is not None and m["stlpips_crop"] <= ref["stlpips_crop"]
    )


# --------------------------------------------------------------------------------------------------
# The sweeps' experiments: what each varies per pair
# --------------------------------------------------------------------------------------------------
STAGE2_BASE_LR = {"lr_grid": 0.02, "lr_network": 1e-3}
"""Stage 2's learning rates the `stage2` sweep starts from (the paper's; the tiny preset's before it)."""


def _run_stage2(spec: "Sweep", split: Validation, names: Sequence[str]) -> dict[str, Any]:
    from gaffer_nerf import relight_field

    # The preset as it was when this sweep ran: Stage 1 on the model's own views, a noise per view,
    # and Stage 2 from the paper's learning rates (the preset's quarter rates are its winner since),
    # so that a rerun measures the same settings.
    r0 = split.relight_cfg
    rcfg = dataclasses.replace(
        r0,
        stage1=dataclasses.replace(r0.stage1, target_detail="model"),
        stage2=dataclasses.replace(r0.stage2, **STAGE2_BASE_LR),
    )
    guide = split.guide(shared_noise=False)
    steps0 = rcfg.stage2.iterations

    def references(split: Validation, pair: Pair, rows: dict[str, Any]) -> dict[str, Any]:
        fit, train, env, gt = pair.fit, pair.scene.train, pair.envmap, pair.ground_truth
        s1 = relight_field(
            fit.field, train, env, guide, rcfg.with_ablation("no-stage2"), split.perceptual_loss
        )
        rows["stage 1 only"] = score(split, s1.field, gt, _stage_seconds(s1.report.stage1))
        sds = relight_field(
            fit.field, train, env, guide, rcfg.with_ablation("sds-only"), split.perceptual_loss
        )
        rows["SDS only"] = score(split, sds.field, gt, _stage_seconds(sds.report.stage2))
        return {"relit_views": s1.relit_views}

    def candidate(
        split: Validation, pair: Pair, name: str, shared: dict[str, Any]
    ) -> dict[str, Any]:
        over = dict(spec.candidates[name])
        over.setdefault("lr_gamma", 0.1 ** (1.0 / int(over.get("iterations", steps0))))
        cfg = dataclasses.replace(rcfg, stage2=dataclasses.replace(rcfg.stage2, **over))
        t0 = time.perf_counter()
        res = relight_field(
            pair.fit.field,
            pair.scene.train,
            pair.envmap,
            guide,
            cfg.with_ablation("full"),
            split.perceptual_loss,
            relit_views=shared["relit_views"],
        )
        wall = time.perf_counter() - t0
        secs = _stage_seconds(res.report.stage2)
        return {**score(split, res.field, pair.ground_truth, secs), "wall_seconds": round(wall, 3)}

    rows = relight_pairs(split, names, references, candidate)
    return {"config": split.config(stage2_iterations_default=steps0), "pairs": rows}


def _run_stage1(spec: "Sweep", split: Validation, names: Sequence[str]) -> dict[str, Any]:
    from gaffer_nerf import relight_field

    # Stage 1 alone, with the noise it was chosen with (per view: the noise choice came after it)
    guide = split.guide(shared_noise=False)
    rcfg = split.relight_cfg.with_ablation("no-stage2")

    def references(split: Validation, pair: Pair, rows: dict[str, Any]) -> dict[str, Any]:
        return {"relit_views": None}  # the first candidate's relit views, reused by the others

    def candidate(
        split: Validation, pair: Pair, name: str, shared: dict[str, Any]
    ) -> dict[str, Any]:
        cfg = dataclasses.replace(
            rcfg, stage1=dataclasses.replace(rcfg.stage1, **spec.candidates[name])
        )
        res = relight_field(
            pair.fit.field,
            pair.scene.train,
            pair.envmap,
            guide,
            cfg,
            split.perceptual_loss,
            relit_views=shared["relit_views"],
        )
        shared["relit_views"] = res.relit_views  # one set of relit views per pair
        return score(split, res.field, pair.ground_truth, _stage_seconds(res.report.stage1))

    rows = relight_pairs(split, names, references, candidate)
    return {"config": split.config(noise="per view"), "pairs": rows}


def _run_noise(spec: "Sweep", split: Validation, names: Sequence[str]) -> dict[str, Any]:
    from gaffer_nerf import relight_field

    rcfg = split.relight_cfg  # the full method with the tiny preset's Stage 1 and Stage 2
    guides = {name: split.guide(**spec.candidates[name]) for name in names}

    def references(split: Validation, pair: Pair, rows: dict[str, Any]) -> dict[str, Any]:
        return {}

    def candidate(
        split: Validation, pair: Pair, name: str, shared: dict[str, Any]
    ) -> dict[str, Any]:
        res = relight_field(
            pair.fit.field,
            pair.scene.train,
            pair.envmap,
            guides[name],
            rcfg,
            split.perceptual_loss,
        )
        r = res.report
        secs = r.relight_views_seconds + _stage_seconds(r.stage1) + _stage_seconds(r.stage2)
        return score(split, res.field, pair.ground_truth, secs)

    rows = relight_pairs(split, names, references, candidate)
    config = split.config(
        stage2_iterations=rcfg.stage2.iterations, stage1_target_detail=rcfg.stage1.target_detail
    )
    return {"config": config, "pairs": rows}


def _run_stage2_detail(spec: "Sweep", split: Validation, names: Sequence[str]) -> dict[str, Any]:
    from gaffer_nerf import relight_field

    rcfg = (
        split.relight_cfg
    )  # the tiny preset: Stage-1 transfer, shared noise, quarter Stage-2 rates
    guide = split.guide()

    def references(split: Validation, pair: Pair, rows: dict[str, Any]) -> dict[str, Any]:
        s1 = relight_field(
            pair.fit.field,
            pair.scene.train,
            pair.envmap,
            guide,
            rcfg.with_ablation("no-stage2"),
            split.perceptual_loss,
        )
        rows["stage 1 only"] = score(
            split, s1.field, pair.ground_truth, _stage_seconds(s1.report.stage1)
        )
        return {"relit_views": s1.relit_views}

    def candidate(
        split: Validation, pair: Pair, name: str, shared: dict[str, Any]
    ) -> dict[str, Any]:
        cfg = dataclasses.replace(
            rcfg, stage2=dataclasses.replace(rcfg.stage2, **spec.candidates[name])
        )
        res = relight_field(
            pair.fit.field,
            pair.scene.train,
            pair.envmap,
            guide,
            cfg,
            split.perceptual_loss,
            relit_views=shared["relit_views"],
        )
        return score(split, res.field, pair.ground_truth, _stage_seconds(res.report.stage2))

    rows = relight_pairs(split, names, references, candidate)
    return {"config": split.config(stage2_iterations=rcfg.stage2.iterations), "pairs": rows}


# The L1 sweep fits (no relighting): its rows are fits, its means per candidate L1.
L1_FIT_SEEDS = (0, 1)
L1_SPHERE_SEEDS = (0, 1, 2, 3)
L1_CURRENT = "8e-05"
"""TensoRF's L1, the preset's before the sweep: the full-frame floor of the rule is taken from it."""


def _l1_fit_config(l1: float, seed: int) -> Any:
    import bench_nerf_sizing as sizing

    from gaffer_nerf import EarlyStoppingConfig, fit_preset

    stop = EarlyStoppingConfig(eval_every=50, patience=2, min_iterations=150)
    base = fit_preset("tiny")
    rule = dataclasses.replace(base.sizing, mode="footprint", max_resolution=sizing.MAX_RESOLUTION)
    return dataclasses.replace(base, seed=seed, early_stopping=stop, sizing=rule, **_l1_weights(l1))


def _l1_weights(l1: float) -> dict[str, float]:
    """A candidate's fit overrides: the initial weight, half of it after the first alpha mask."""
    return {"l1_weight_initial": l1, "l1_weight_rest": l1 / 2}


def _run_l1(spec: "Sweep", quick: bool, names: Sequence[str]) -> dict[str, Any]:
    """Every object of both validation splits fitted with the footprint sizing rule (17 fitted train
    views, early stopping on 3 others, 300 iterations of 1024 rays) per candidate and fit seed, scored
    on the 5 test views under the input lighting; and, recorded beside (not part of the rule), the
    largest box side after the first alpha mask on the analytic sphere of the gaffer-nerf tests."""
    import bench_nerf_sizing as sizing

    from gaffer_nerf import fit_tensorf
    from gaffer_nerf.evaluate import evaluate_field
    from gaffer_nerf.testing import orbit_cameras, quick_fit_config, scene_envmap, sphere_viewset

    values = [spec.candidates[n]["l1_weight_initial"] for n in names]
    fits = []
    for split in (real.VALIDATION,) if quick else (real.VALIDATION, real.VALIDATION_B):
        for folder in sizing.real_object_folders(split, quick):
            scene, fitted, heldout = sizing.input_lighting_views(folder)
            for l1 in values:
                for seed in L1_FIT_SEEDS[:1] if quick else L1_FIT_SEEDS:
                    res = fit_tensorf(fitted, _l1_fit_config(l1, seed), heldout=heldout)
                    rep, _ = evaluate_field(res.field, scene.test, perceptual=None)
                    r = res.report
                    fits.append(
                        {
                            "split": split.name,
                            "object": folder.name,
                            "l1_initial": l1,
                            "seed": seed,
                            "final_grid": list(r.final_grid),
                            "iterations_run": r.iterations_run,
                            "seconds": round(r.seconds, 3),
                            "psnr_object_db": round(float(rep.mean_object_raw.psnr), 3),
                            "psnr_full_frame_db": round(float(rep.mean_raw.psnr), 3),
                        }
                    )
                    common.log(
                        f"  {split.name} {folder.name} L1 {l1:g} seed {seed}: grid "
                        f"{'x'.join(map(str, r.final_grid))}, object "
                        f"{fits[-1]['psnr_object_db']:.2f} dB, full "
                        f"{fits[-1]['psnr_full_frame_db']:.2f} dB"
                    )
    train = sphere_viewset(orbit_cameras(8), scene_envmap(0))
    boxes = []
    for l1 in values:
        for seed in L1_SPHERE_SEEDS[:1] if quick else L1_SPHERE_SEEDS:
            res = fit_tensorf(train, quick_fit_config(seed=seed, **_l1_weights(l1)))
            boxes.append(
                {
                    "l1_initial": l1,
                    "seed": seed,
                    "box_side": round(float(res.field.aabb_size.max()), 3),
                }
            )
    config = {
        "candidates_l1_initial": values,
        "l1_rest": "half of the initial weight",
        "fit_seeds": list(L1_FIT_SEEDS),
        "splits": ["validation", "validation-b"],
    }
    return {"config": config, "fits": fits, "sphere_boxes": boxes}


def l1_means(payload: dict[str, Any]) -> Means:
    """Per candidate L1 (named by `{:g}`): mean object and full-frame PSNR, worst fit, seconds per fit,
    and the sphere's box sides."""
    out: Means = {}
    for l1 in payload["config"]["candidates_l1_initial"]:
        rs = [r for r in payload["fits"] if r["l1_initial"] == l1]
        out[f"{l1:g}"] = {
            "l1_initial": l1,
            "fits": len(rs),
            "psnr_object_db": round(sum(r["psnr_object_db"] for r in rs) / len(rs), 3),
            "psnr_full_frame_db": round(sum(r["psnr_full_frame_db"] for r in rs) / len(rs), 3),
            "min_object_db": round(min(r["psnr_object_db"] for r in rs), 3),
            "seconds": round(sum(r["seconds"] for r in rs) / len(rs), 3),
            "sphere_box_sides": [
                b["box_side"] for b in payload["sphere_boxes"] if b["l1_initial"] == l1
            ],
        }
    return out


# --------------------------------------------------------------------------------------------------
# The rules (each fixed before its sweep ran)
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Rule:
    """How a sweep picks its setting from the means: `pick` returns the chosen name and any numbers
    the rule derived on the way (recorded in the summary)."""

    text: str
    pick: Callable[["Sweep", Means], tuple[str, dict[str, Any]]]


def _pick_stage2(spec: "Sweep", m: Means) -> tuple[str, dict[str, Any]]:
    settings = [n for n in m if n in spec.candidates]
    ok = [n for n in settings if _lpips_no_worse(m[n], m["stage 1 only"])]
    chosen = max(ok or settings, key=lambda n: m[n]["psnr_object_db"])
    return chosen, {"chosen_from_lpips_filter": bool(ok)}


STAGE1_PSNR_SLACK_DB = 0.25
"""How much mean object PSNR a Stage-1 target may give up against "model" to be chosen for ST-LPIPS."""


def _pick_stage1(spec: "Sweep", m: Means) -> tuple[str, dict[str, Any]]:
    floor = m["model"]["psnr_object_db"] - STAGE1_PSNR_SLACK_DB
    pool = [n for n in m if n in spec.candidates and m[n]["psnr_object_db"] >= floor]
    if m["model"]["stlpips_crop"] is None:
        chosen = "model"  # no perceptual metric: nothing to choose for
    else:
        chosen = min(pool, key=lambda n: m[n]["stlpips_crop"])
    return chosen, {"psnr_floor_db": round(floor, 4)}


def _pick_noise(spec: "Sweep", m: Means) -> tuple[str, dict[str, Any]]:
    a, b = m["per-view noise"], m["shared noise"]
    adopt = b["psnr_object_db"] > a["psnr_object_db"] and _lpips_no_worse(b, a)
    return ("shared noise" if adopt else "per-view noise"), {}


def _pick_stage2_detail(spec: "Sweep", m: Means) -> tuple[str, dict[str, Any]]:
    base = m["model"]
    ok = [n for n in m if n in spec.candidates and n != "model" and _lpips_no_worse(m[n], base)]
    best = max(ok, key=lambda n: m[n]["psnr_object_db"]) if ok else None
    adopt = best is not None and m[best]["psnr_object_db"] > base["psnr_object_db"]
    return (best if adopt and best else "model"), {}


L1_FULL_FRAME_SLACK_DB = 0.1
L1_TIE_DB = 0.1


def _pick_l1(spec: "Sweep", m: Means) -> tuple[str, dict[str, Any]]:
    floor = m[L1_CURRENT]["psnr_full_frame_db"] - L1_FULL_FRAME_SLACK_DB
    allowed = [n for n in m if m[n]["psnr_full_frame_db"] >= floor]
    best = max(m[n]["psnr_object_db"] for n in allowed)
    tied = [n for n in allowed if m[n]["psnr_object_db"] >= best - L1_TIE_DB]
    return max(tied, key=lambda n: m[n]["l1_initial"]), {}


# --------------------------------------------------------------------------------------------------
# The sweep table
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sweep:
    """One validation sweep.

    Attributes:
        name: the result file, `results/<name>.json` / `.png`.
        chooses: the preset setting it decides.
        preset: `(preset, field)` whose attributes the candidates' overrides set, e.g.
            `("relight", "stage2")` for `relight_preset("tiny").stage2`.
        candidates: name -> the overrides of that field.
        quick: the candidates of a `--quick` run.
        rule: how the choice is made, fixed before the run.
        recorded: the choice the committed result made (and the preset ships).
        run: the experiment.
        reference: the row the per-pair wins are counted against.
        wins: `(key, label, test)` of the per-pair wins column.
        columns: `(first column, seconds column)` headers of the table.
        lpips_digits: decimals of ST-LPIPS in the table.
        superseded: why the preset no longer ships `recorded` (a later choice on other data), or
            "" while it does.
    """

    name: str
    chooses: str
    preset: tuple[str, str]
    candidates: Mapping[str, Mapping[str, Any]]
    quick: tuple[str, ...]
    rule: Rule
    recorded: str
    run: Callable[..., dict[str, Any]]
    reference: str = ""
    wins: tuple[str, str, Callable[[dict, dict], bool]] | None = None
    columns: tuple[str, str] = ("setting", "seconds")
    lpips_digits: int = 4
    superseded: str = ""

    @property
    def relights(self) -> bool:
        """A relighting sweep (pairs); else the L1 sweep (fits)."""
        return self.wins is not None

    def means(self, payload: dict[str, Any]) -> Means:
        """The means of the payload's own rows (pairs or fits)."""
        if self.wins is None:
            return l1_means(payload)
        key, _, test = self.wins
        return pair_means(payload["pairs"], self.reference, key, test)

    def summary(self, payload: dict[str, Any]) -> dict[str, Any]:
        """Means, the rule's choice and what the rule derived."""
        means = self.means(payload)
        chosen, derived = self.rule.pick(self, means)
        return {"means": means, "chosen": chosen, **derived}

    def choice(self, chosen: str) -> dict[str, Any]:
        """The `choice` block of the result: the setting, the rule and the candidates it chose among."""
        return {
            "sweep": self.name,
            "chooses": self.chooses,
            "preset_field": f"{self.preset[0]}_preset('tiny')"
            + (f".{self.preset[1]}" if self.preset[1] else ""),
            "candidates": list(self.candidates),
            "rule": self.rule.text,
            "chosen": chosen,
            "chosen_overrides": dict(self.candidates[chosen]),
        }

    def shipped(self) -> dict[str, Any]:
        """The preset's current values of the recorded choice's overrides."""
        from gaffer_nerf import fit_preset, relight_preset

        kind, field = self.preset
        obj: Any = fit_preset("tiny") if kind == "fit" else relight_preset("tiny")
        if field:
            obj = getattr(obj, field)
        return {k: getattr(obj, k) for k in self.candidates[self.recorded]}


_TRANSFER = {"target_detail": "transfer"}
SWEEPS: dict[str, Sweep] = {
    "stage2": Sweep(
        name="nerf_stage2_val",
        chooses="Stage 2's learning rates, t* range and schedule, loss weights and step count",
        preset=("relight", "stage2"),
        candidates={
            "paper shape": {},
            "t* 0.2->0.02": {"t_start": 0.2, "t_end": 0.02},
            "t* 0.1->0.02": {"t_start": 0.1, "t_end": 0.02},
            "authors t*": {"t_schedule": "authors"},
            "lr / 4": {"lr_grid": 0.005, "lr_network": 2.5e-4},
            "lr / 4, t* 0.2": {
                "lr_grid": 0.005,
                "lr_network": 2.5e-4,
                "t_start": 0.2,
                "t_end": 0.02,
            },
            "L1 only": {"perceptual_weight": 0.0},
            "perceptual only": {"l1_weight": 0.0, "perceptual_weight": 1.0},
            "60 steps": {"iterations": 60},
            "60 steps, lr / 4": {"iterations": 60, "lr_grid": 0.005, "lr_network": 2.5e-4},
        },
        quick=("paper shape", "t* 0.2->0.02", "lr / 4"),
        rule=Rule(
            "highest mean object PSNR (raw) among the Stage-2 settings whose mean ST-LPIPS is "
            "no worse than Stage 1 only; else the highest PSNR",
            _pick_stage2,
        ),
        recorded="lr / 4",
        reference="stage 1 only",
        wins=("wins_vs_stage1_psnr", "> Stage 1 (pairs)", higher_psnr),
        columns=("setting", "Stage-2 s"),
        lpips_digits=3,
        run=_run_stage2,
    ),
    "stage1": Sweep(
        name="nerf_stage1_val",
        chooses="Stage 1's targets: the model's relit views, or their change of shading transferred",
        preset=("relight", "stage1"),
        candidates={
            "model": {"target_detail": "model"},
            **{
                f"transfer r{r}": {**_TRANSFER, "transfer_radius_px": r} for r in (0, 1, 2, 3, 4, 6)
            },
        },
        quick=("model", "transfer r2"),
        rule=Rule(
            "lowest mean ST-LPIPS among the settings whose mean object PSNR (raw) is at most "
            f"{STAGE1_PSNR_SLACK_DB} dB below 'model' ('model' included)",
            _pick_stage1,
        ),
        recorded="transfer r2",
        reference="model",
        wins=("stlpips_wins_vs_model", "ST-LPIPS < model (pairs)", lower_stlpips),
        columns=("Stage 1 targets", "Stage-1 s"),
        run=_run_stage1,
    ),
    "noise": Sweep(
        name="nerf_noise_val",
        chooses="one initial noise for every relit training view, or one per view",
        preset=("relight", "diffusion"),
        candidates={
            "per-view noise": {"shared_noise": False},
            "shared noise": {"shared_noise": True},
        },
        quick=("per-view noise", "shared noise"),
        rule=Rule(
            "shared noise if the full method's mean object PSNR (raw) is higher with it and "
            "its mean ST-LPIPS no worse",
            _pick_noise,
        ),
        recorded="shared noise",
        superseded=(
            "per-view noise since the 128 px CLI-defaults validation (bench_nerf_cli_defaults.py "
            "--validation, results/nerf_cli_defaults_val.json): with one shared noise every "
            "training view of gaffer-tiny's one-step sample carries the same colour error, which "
            "the field cannot average away"
        ),
        reference="per-view noise",
        wins=("psnr_wins_vs_per_view", "PSNR > per-view (pairs)", higher_psnr),
        columns=("full method", "relight s"),
        run=_run_noise,
    ),
    "stage2-detail": Sweep(
        name="nerf_stage2_detail_val",
        chooses="Stage 2's guidance target: the model's denoised view, or the render times its "
        "change of shading",
        preset=("relight", "stage2"),
        candidates={
            "model": {"target_detail": "model"},
            **{f"transfer r{r}": {**_TRANSFER, "transfer_radius_px": r} for r in (4, 8, 16)},
        },
        quick=("model", "transfer r8"),
        rule=Rule(
            "among the 'transfer' radii with mean ST-LPIPS no worse than 'model', the highest mean "
            "object PSNR, adopted only if above 'model''s; else 'model'",
            _pick_stage2_detail,
        ),
        recorded="model",
        reference="model",
        wins=("psnr_wins_vs_model", "PSNR > model (pairs)", higher_psnr),
        columns=("Stage 2 target", "Stage-2 s"),
        run=_run_stage2_detail,
    ),
    "l1": Sweep(
        name="nerf_l1_val",
        chooses="the fit's density L1 (initial weight; half of it after the first alpha mask)",
        preset=("fit", ""),
        candidates={f"{v:g}": _l1_weights(v) for v in (8e-5, 2e-5, 8e-6, 2e-6, 0.0)},
        quick=("8e-05", "8e-06"),
        rule=Rule(
            "highest mean object PSNR among candidates with mean full-frame PSNR >= current "
            f"({L1_CURRENT}) - {L1_FULL_FRAME_SLACK_DB} dB; ties within {L1_TIE_DB} dB -> largest L1",
            _pick_l1,
        ),
        recorded="8e-06",
        columns=("L1 (initial / after mask)", "s per fit"),
        run=_run_l1,
    ),
}
"""Every validation sweep, by the name the command line takes."""


# --------------------------------------------------------------------------------------------------
# Result files: recorded choice, check, tables, charts
# --------------------------------------------------------------------------------------------------
def recorded_rule(payload: dict[str, Any]) -> str | None:
    """The rule text a result file recorded (`choice`, else its config, as written before `choice`)."""
    if "choice" in payload:
        return payload["choice"]["rule"]
    cfg = payload.get("config", {})
    return cfg.get("selection_rule") or cfg.get("rule")


def recorded_means(spec: Sweep, payload: dict[str, Any]) -> Means:
    """The means a result file recorded (the L1 sweep's as a list, one entry per candidate)."""
    if spec.relights:
        return payload["summary"]["means"]
    return {f"{m['l1_initial']:g}": m for m in payload["means"]}


def recorded_choice(spec: Sweep, payload: dict[str, Any]) -> str:
    """The choice a result file recorded."""
    if "choice" in payload:
        return payload["choice"]["chosen"]
    if spec.relights:
        return payload["summary"]["chosen"]
    return f"{payload['chosen']['l1_initial']:g}"


def check(spec: Sweep, payload: dict[str, Any]) -> list[str]:
    """What is wrong with a committed result (empty: the recorded choice follows from the recorded
    rows under the rule, and the preset ships it)."""
    problems = []
    means = spec.means(payload)
    if means != recorded_means(spec, payload):
        problems.append("the recorded means are not the means of the recorded rows")
    chosen, _ = spec.rule.pick(spec, recorded_means(spec, payload))
    got = recorded_choice(spec, payload)
    if chosen != got:
        problems.append(f"the rule picks {chosen!r} from the recorded means, the file says {got!r}")
    if got != spec.recorded:
        problems.append(f"the file chose {got!r}, the sweep table records {spec.recorded!r}")
    if recorded_rule(payload) != spec.rule.text:
        problems.append(f"the file's rule {recorded_rule(payload)!r} is not the table's")
    if set(means) - {"unrelit", "stage 1 only", "SDS only"} != set(spec.candidates):
        problems.append("the file's candidates are not the table's")
    want = dict(spec.candidates[spec.recorded])
    shipped = spec.shipped()
    if not spec.superseded and any(shipped[k] != v for k, v in want.items()):
        problems.append(f"the preset ships {shipped}, the recorded choice is {want}")
    return problems


def _legacy_fields(spec: Sweep, payload: dict[str, Any], summary: dict[str, Any]) -> None:
    """Write the summary where the sweep's files keep it (the L1 sweep: top-level means / chosen)."""
    if spec.relights:
        payload["summary"] = summary
        payload["config"]["settings"] = {
            n: dict(spec.candidates[n]) for n in summary["means"] if n in spec.candidates
        }
        payload["config"]["selection_rule"] = spec.rule.text
    else:
        payload["means"] = list(summary["means"].values())
        payload["chosen"] = summary["means"][summary["chosen"]]
        payload["config"]["rule"] = spec.rule.text
    payload["choice"] = spec.choice(summary["chosen"])


def markdown(spec: Sweep, payload: dict[str, Any]) -> str:
    """The Markdown table of the result and the line naming the chosen setting."""
    means = recorded_means(spec, payload)
    chosen = recorded_choice(spec, payload)
    first, seconds = spec.columns
    if spec.wins is None:
        lines = [
            f"| {first} | object PSNR | worst fit | full frame | {seconds} | "
            "sphere box side, seeds 0-3 |",
            "|---|---|---|---|---|---|",
        ]
        for name, m in means.items():
            star = " (chosen)" if name == chosen else ""
            lines.append(
                f"| {m['l1_initial']:g} / {m['l1_initial'] / 2:g}{star} | "
                f"{m['psnr_object_db']:.2f} | {m['min_object_db']:.2f} | "
                f"{m['psnr_full_frame_db']:.2f} | {m['seconds']:.1f} | "
                f"{', '.join(f'{b:.2f}' for b in m['sphere_box_sides'])} |"
            )
        return "\n".join(lines)
    key, label, _ = spec.wins
    digits = spec.lpips_digits
    lines = [
        f"| {first} | object PSNR raw | aligned | SSIM | ST-LPIPS | full frame | {seconds} | "
        f"{label} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, v in means.items():
        lp = "-" if v["stlpips_crop"] is None else f"{v['stlpips_crop']:.{digits}f}"
        lines.append(
            f"| {name} | {v['psnr_object_db']:.2f} | {v['psnr_object_aligned_db']:.2f} | "
            f"{v['ssim_object']:.3f} | {lp} | {v['psnr_full_frame_db']:.2f} | "
            f"{v['seconds']:.1f} | {v[key]}/{len(payload['pairs'])} |"
        )
    return "\n".join([*lines, "", f"Chosen by the fixed rule: **{chosen}**."])


def plot(spec: Sweep, payload: dict[str, Any]) -> Any:
    """Object PSNR against ST-LPIPS per setting (the L1 sweep: against seconds per fit); the chosen
    setting red, the reference rows grey."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    means = recorded_means(spec, payload)
    chosen = recorded_choice(spec, payload)
    fig, ax = plt.subplots(figsize=(7, 5))
    xkey = "stlpips_crop" if spec.relights else "seconds"
    for name, m in means.items():
        if m[xkey] is None:
            continue
        grey = name not in spec.candidates
        colour = "tab:red" if name == chosen else "#888888" if grey else "tab:blue"
        ax.scatter(m[xkey], m["psnr_object_db"], color=colour)
        ax.annotate(
            name,
            (m[xkey], m["psnr_object_db"]),
            fontsize=8,
            xytext=(3, 3),
            textcoords="offset points",
        )
    ax.set_xlabel(
        "ST-LPIPS on the object crop (shift-tolerant AlexNet; lower is better)"
        if spec.relights
        else "seconds per fit (mean)"
    )
    ax.set_ylabel("object-mask PSNR, raw (dB)")
    ax.grid(alpha=0.3)
    cfg = payload["config"]
    where = (
        f"{len(payload['pairs'])} pairs: {', '.join(cfg['objects'])} x "
        f"{', '.join(cfg['target_lightings'])}"
        if spec.relights
        else f"{len(payload['fits'])} fits"
    )
    ax.set_title(
        f"{spec.chooses}\non the validation split ({where}); chosen: {chosen}; "
        f"{common.short_device(payload['machine'])}",
        fontsize=8,
    )
    fig.tight_layout()
    return fig


# --------------------------------------------------------------------------------------------------
# Command line
# --------------------------------------------------------------------------------------------------
def _finish(spec: Sweep, payload: dict[str, Any], update_baseline: bool, name: str) -> None:
    _legacy_fields(spec, payload, spec.summary(payload))
    for path in common.write_results(name, payload, plot(spec, payload), update_baseline):
        common.log(f"wrote {path}")
    if update_baseline and spec.name == "nerf_l1_val" and not payload["config"].get("quick"):
        common.update_readme(spec.name, markdown(spec, payload))
    print(markdown(spec, payload))
    print(f"chosen: {payload['choice']['chosen']} ({spec.rule.text})")


def cmd_run(spec: Sweep, args: argparse.Namespace) -> int:
    """Run the sweep; a part (`--objects`) is written to `results/runs/` for `merge`."""
    if args.objects and not spec.relights:
        raise SystemExit("--objects: only the relighting sweeps run in parts; drop it for `l1`")
    threads = common.set_threads(args.threads or (0 if spec.relights else 1))
    meta = common.machine(threads)
    t0 = time.perf_counter()
    names = spec.quick if args.quick else tuple(spec.candidates)
    if spec.relights:
        only = args.objects.split(",") if args.objects else None
        result = spec.run(spec, prepare(args.quick, args.seed, only), names)
        result["config"]["settings"] = {n: dict(spec.candidates[n]) for n in names}
        result["config"]["selection_rule"] = spec.rule.text
    else:
        result = spec.run(spec, args.quick, names)
        result["config"]["quick"] = args.quick
    name = spec.name + ("-quick" if args.quick else "")
    payload: dict[str, Any] = {"name": name, "machine": meta, **result}
    payload["seconds"] = {"total_wall": round(time.perf_counter() - t0, 1)}
    if args.objects:
        common.RUNS.mkdir(parents=True, exist_ok=True)
        part = common.RUNS / f"{spec.name}-part-{'+'.join(only or [])}.json"
        part.write_text(json.dumps(payload, indent=2) + "\n")
        common.log(f"wrote {part}")
        return 0
    _finish(spec, payload, args.update_baseline, name)
    return 0


def cmd_merge(spec: Sweep, paths: Sequence[Path], update_baseline: bool) -> int:
    """One result from the parts written by `run --objects` (same settings, disjoint objects)."""
    parts = [json.loads(p.read_text()) for p in paths]
    first = parts[0]
    for part in parts[1:]:
        a = {k: v for k, v in part["config"].items() if k != "objects"}
        b = {k: v for k, v in first["config"].items() if k != "objects"}
        if a != b:
            raise SystemExit(f"{paths[0]} and another part differ in their config")
    rows = sorted(
        (p for part in parts for p in part["pairs"]), key=lambda p: (p["object"], p["target"])
    )
    config = dict(first["config"])
    config["objects"] = sorted({p["object"] for p in rows})
    payload = {
        "name": spec.name,
        "machine": first["machine"],
        "machines_of_parts": [part["machine"] for part in parts],
        "parts": [str(p.name) for p in paths],
        "config": config,
        "pairs": rows,
        "seconds": {"total_wall_of_parts": [part["seconds"]["total_wall"] for part in parts]},
    }
    _finish(spec, payload, update_baseline, spec.name)
    return 0


def _selected(names: Sequence[str]) -> list[Sweep]:
    unknown = [n for n in names if n not in SWEEPS]
    if unknown:
        raise SystemExit(f"unknown sweep {unknown[0]!r}; choose from {', '.join(SWEEPS)}")
    return [SWEEPS[n] for n in names or SWEEPS]


def cmd_check(names: Sequence[str]) -> int:
    """Check each committed result against its rule and the preset; exit 1 on any problem."""
    bad = 0
    for spec in _selected(names):
        payload = json.loads((common.RESULTS / f"{spec.name}.json").read_text())
        problems = check(spec, payload)
        bad += bool(problems)
        status = "; ".join(problems) if problems else "ok"
        status += f" (superseded: {spec.superseded})" if spec.superseded else ""
        print(f"{spec.name}: chose {recorded_choice(spec, payload)!r} for {spec.chooses}: {status}")
    return 1 if bad else 0


def cmd_record(names: Sequence[str]) -> int:
    """Rewrite the summary and `choice` of each committed result from its own rows (nothing reruns;
    the measured rows, machine and timings stay as they are)."""
    for spec in _selected(names):
        path = common.RESULTS / f"{spec.name}.json"
        payload = json.loads(path.read_text())
        summary = spec.summary(payload)
        if summary["means"] != recorded_means(spec, payload):
            raise SystemExit(f"{path}: the recorded means differ from its rows; rerun the sweep")
        _legacy_fields(spec, payload, summary)
        path.write_text(json.dumps(payload, indent=2, sort_keys=False) + "\n")
        common.log(f"recorded {spec.name}: {summary['chosen']}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("list", help="the sweep table: candidates, rule, recorded choice")
    for cmd, text in (
        ("check", "check the committed results against their rules and the preset"),
        ("record", "rewrite the committed results' summary and choice from their rows"),
    ):
        p = sub.add_parser(cmd, help=text)
        p.add_argument("sweeps", nargs="*", metavar="SWEEP", help=f"any of {', '.join(SWEEPS)}")
    run = sub.add_parser("run", help="run a sweep")
    run.add_argument("sweep", choices=list(SWEEPS))
    run.add_argument("--quick", action="store_true", help="one pair, two or three candidates")
    run.add_argument("--update-baseline", action="store_true", help="also write results/<name>")
    run.add_argument(
        "--threads", type=int, default=0, help="torch threads (0: the sweep's default)"
    )
    run.add_argument("--seed", type=int, default=0, help="fit and relighting seed")
    run.add_argument("--objects", help="comma-separated object folders: run only these (a part)")
    merge = sub.add_parser("merge", help="merge the parts written by `run --objects`")
    merge.add_argument("sweep", choices=[k for k, s in SWEEPS.items() if s.relights])
    merge.add_argument("parts", nargs="+", type=Path)
    merge.add_argument("--update-baseline", action="store_true")
    args = parser.parse_args(argv)
    if args.command == "list":
        for key, spec in SWEEPS.items():
            print(f"{key} -> results/{spec.name}.json: {spec.chooses}")
            print(f"  candidates: {'; '.join(spec.candidates)}")
            print(f"  rule: {spec.rule.text}")
            print(f"  recorded choice: {spec.recorded} {dict(spec.candidates[spec.recorded])}")
        return 0
    if args.command == "check":
        return cmd_check(args.sweeps)
    if args.command == "record":
        return cmd_record(args.sweeps)
    if args.command == "merge":
        return cmd_merge(SWEEPS[args.sweep], args.parts, args.update_baseline)
    return cmd_run(SWEEPS[args.sweep], args)


if __name__ == "__main__":
    sys.exit(main())
