"""gaffer-nerf on real renders with the shipped gaffer-tiny: the paper's 3D table and ablations at CPU scale.

Three procedural objects gaffer-tiny never saw (`gaffer-data recipe --procedural 3
--seed 41`; gaffer-tiny's splits are seeds 21-24) are rendered by gaffer-data (`render-multiview`,
Blender Cycles, 64 px, 32 samples + denoiser, 20 train + 5 test views on the default sphere layout)
under three lightings each: `city` (one of gaffer-tiny's four training HDRIs) is the INPUT lighting
the field is fitted to, and `courtyard` and `sunset` (gaffer-tiny's TEST-split HDRIs, used in none
of its choices) are the held-out TARGET lightings, whose Cycles renders of the test views are the
ground truth. gaffer-data draws each lighting's flip and yaw per object; the targets are read back
with them (`gaffer_nerf.data.load_lighting_envmap`).

Per object: one fit (`fit_preset("tiny")` with the sizing rule, `GridSizingConfig(mode="footprint")`:
the pixel footprint capped by the iteration budget, `FIT_ITERATIONS` x 1024 rays). Per (object,
target lighting), the field is relit with the shipped default model (gaffer-tiny, loaded as with no
`--checkpoint`, sampled with its own suggestion: 1 DDIM step, guidance 1, mirror average, "default"
encoding) under

- `unrelit`: the input field as it is (the floor);
- `stage1`: Stage 1 only (ablation "no-stage2");
- `full`: Stage 1 + Stage 2 with the guidance loss (the paper's method);
- `sds-only`: Stage 2 with SDS on the input field, no Stage 1 (the paper's SDS baseline);
- `sds-stage2`: Stage 1 + Stage 2 with SDS in place of the guidance loss;
- `full-whole` (the framing ablation): `full` with the model shown whole views
  (`DiffusionSamplingConfig(object_fraction="whole")`) instead of the object-centred crops it was
  trained on (gaffer-tiny's own framing, 0.75, used by every other variant);
- `full-per-view` (the consistency ablation): `full` with every training view relit from its own
  initial noise (`DiffusionSamplingConfig(shared_noise=False)`, the paper's way) instead of the one
  noise all views share (the tiny preset's, chosen on the validation split:
  `nerf_sweep.py run noise`);
- `stage1-oracle` (reference, not a method): Stage 1 fitted to the Cycles renders of the TRAINING
  views under the target lighting instead of gaffer-tiny's relit views: what Stage 1 could reach with
  a perfect 2D relighting at this field and budget.

Stage 1 `STAGE1_ITERATIONS` x 1024 rays, Stage 2 `STAGE2_ITERATIONS` full views (both from
`relight_preset("tiny")`, counts raised). The tiny preset's other choices were made on a VALIDATION
split disjoint from this one in objects and target lightings, one after the other: Stage 2's
learning rates (`nerf_sweep.py run stage2`), Stage 1's targets (the model's change of shading
transferred onto the input views, radius 2 px: `run stage1`) and one initial noise shared by every
view (`run noise`); this test split is scored with them. The relit
training views (Stage 1's targets) are computed once per pair and reused by `full` and `sds-stage2`
(they are deterministic: seeded noise); their seconds are counted in every variant that uses them.

Scores on the 5 test views under the target lighting (`gaffer_nerf.evaluate.evaluate_field`): PSNR
and SSIM over the object mask (alpha-weighted), shift-tolerant LPIPS (ST-LPIPS, AlexNet, NOT standard
LPIPS) on the object's crop, the mask-aligned PSNR (per-channel scale fitted in the mask, as the
paper's metrics), and full-frame PSNR; means over the test views, then over the (object, target)
pairs. Seconds per phase: fit (per object), weight cache, encoding, relit views, Stage 1, Stage 2.

Multi-view consistency: every field is also rendered along a closed 16-frame orbit
(one ring at 30 degrees elevation, a second gaffer-data render of the same objects under the same
lighting draws, `orbit_renders`), and `gaffer_nerf.flicker.temporal_flicker` scores the sequence
against the Cycles orbit under the target lighting: the mean frame-to-frame change the ground truth
does not have (0 = none), and the ratio of frame-to-frame energies (relit / truth).

The renders are made once and cached (needs gaffer-data[render], Blender's bpy) under
`$GAFFER_BENCH_NERF_REAL_DATA` (default `results/runs/nerf_real_data/`, git-ignored).

Run: `python benchmarks/bench_nerf_real.py [--quick] [--update-baseline] [--threads N] [--seed S]`
(default 2 threads; full: about 15-20 minutes on 2 free cores after the renders; `--quick`: one
object, one target, smaller counts, a couple of minutes).
"""

import dataclasses
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
import torch

NAME = "nerf_real"
RESOLUTION = 64
SAMPLES = 32
TRAIN_VIEWS = 20
TEST_VIEWS = 5
OBJECT_SEED = 41
NUM_OBJECTS = 3
RENDER_SEED = 41
INPUT_HDRI = "city"
"""A training HDRI of gaffer-tiny (its model card): the input lighting."""
TARGET_HDRIS = ("courtyard", "sunset")
"""gaffer-tiny's test-split HDRIs (its model card): the held-out targets."""

FIT_ITERATIONS = 600
STAGE1_ITERATIONS = 300
STAGE2_ITERATIONS = 20
SDS_LR = {"lr_grid": 0.02, "lr_network": 1e-3}
"""Stage 2's learning rates for the SDS variants: the paper's (`Stage2Config` defaults)."""
QUICK = {"objects": 1, "targets": 1, "fit": 300, "stage1": 100, "stage2": 6}

VARIANTS = (
    "unrelit",
    "stage1",
    "full",
    "sds-only",
    "sds-stage2",
    "full-whole",
    "full-per-view",
    "stage1-oracle",
)
ABLATION_OF = {
    "stage1": "no-stage2",
    "full": "full",
    "sds-only": "sds-only",
    "sds-stage2": "sds-stage2",
    "full-whole": "full",
    "full-per-view": "full",
    "stage1-oracle": "no-stage2",
}
LABELS = {
    "unrelit": "unrelit field",
    "stage1": "Stage 1 only",
    "full": "Stage 1 + 2 (full)",
    "sds-only": "SDS only",
    "sds-stage2": "Stage 1 + SDS",
    "full-whole": "full, whole views (no framing)",
    "full-per-view": "full, per-view noise",
    "stage1-oracle": "Stage 1, oracle targets",
}
COLOURS = {
    "unrelit": "#888888",
    "stage1": "tab:blue",
    "full": "tab:red",
    "sds-only": "tab:orange",
    "sds-stage2": "tab:purple",
    "full-whole": "tab:brown",
    "full-per-view": "tab:pink",
    "stage1-oracle": "tab:green",
}


# ---------------------------------------------------------------------------------------- data


@dataclasses.dataclass(frozen=True)
class Split:
    """Which objects and target lightings a run uses: the test split (this benchmark) or the
    validation split Stage 2's settings are chosen on (`nerf_sweep.py`).

    Objects and target HDRIs are disjoint between the two; the input lighting is the same.
    """

    name: str
    object_seed: int
    render_seed: int
    targets: tuple[str, ...]
    targets_are: str
    env_var: str
    folder: str

    def data_root(self) -> Path:
        return Path(os.environ.get(self.env_var) or common.RUNS / self.folder)


TEST = Split(
    "test",
    OBJECT_SEED,
    RENDER_SEED,
    TARGET_HDRIS,
    "gaffer-tiny's test-split HDRIs (model card)",
    "GAFFER_BENCH_NERF_REAL_DATA",
    "nerf_real_data",
)
VALIDATION = Split(
    "validation",
    42,
    42,
    ("forest", "studio"),
    "gaffer-tiny's validation-split HDRIs (model card)",
    "GAFFER_BENCH_NERF_VAL_DATA",
    "nerf_real_val_data",
)


VALIDATION_B = Split(
    "validation-b",
    43,
    43,
    (),
    "none (input lighting only: a second validation split for grid sizing)",
    "GAFFER_BENCH_NERF_VAL_B_DATA",
    "nerf_real_val_b_data",
)
"""Three more unseen objects (`--seed 43`) under the input lighting only: `bench_nerf_sizing.py
--real validation-b`, more objects to choose a sizing rule on."""
SPLITS = {s.name: s for s in (TEST, VALIDATION, VALIDATION_B)}


def data_root() -> Path:
    return TEST.data_root()


def renders(need: int = NUM_OBJECTS, split: Split = TEST) -> Path:
    """The gaffer-data multi-view render of the held-out objects (made once, then reused).

    Reused as soon as `need` objects are complete (their `transforms_test.json` is written last).
    """
    root = split.data_root()
    out = root / "renders"
    objects = sorted(
        p for p in (out / "objects").glob("*") if (p / "transforms_test.json").is_file()
    )
    if (out / "dataset.json").is_file() and len(objects) >= need:
        return out
    exe = Path(sys.executable).parent
    root.mkdir(parents=True, exist_ok=True)
    if not (root / "recipe" / "objects").is_dir():
        subprocess.run(
            [
                str(exe / "gaffer-data"),
                "recipe",
                "--procedural",
                str(NUM_OBJECTS),
                "--seed",
                str(split.object_seed),
                str(root / "recipe"),
            ],
            check=True,
        )
    held = {"objects": root / "held" / "objects", "envmaps": root / "held" / "envmaps"}
    for folder in held.values():
        folder.mkdir(parents=True, exist_ok=True)
    for mesh in sorted((root / "recipe" / "objects" / "procedural").iterdir()):
        shutil.copy2(mesh, held["objects"] / mesh.name)
    for name in (INPUT_HDRI, *split.targets):
        shutil.copy2(root / "recipe" / "envmaps" / f"{name}.exr", held["envmaps"] / f"{name}.exr")
    common.log(f"  rendering {NUM_OBJECTS} objects at {RESOLUTION} px into {out} (once; resumable)")
    subprocess.run(
        [
            str(exe / "gaffer-data"),
            "render-multiview",
            "--objects",
            str(held["objects"]),
            "--envmaps",
            str(held["envmaps"]),
            "--out",
            str(out),
            "--lightings",
            str(1 + len(split.targets)),
            "--resolution",
            str(RESOLUTION),
            "--samples",
            str(SAMPLES),
            "--seed",
            str(split.render_seed),
            "--workers",
            "1",
            "--train-views",
            str(TRAIN_VIEWS),
            "--test-views",
            str(TEST_VIEWS),
            "--no-progress",
        ],
        check=True,
    )
    return out


ORBIT_VIEWS = 16
"""Frames of the closed test orbit the flicker metric runs along."""
ORBIT_ELEVATION_DEG = 30.0


def orbit_renders(split: Split = TEST) -> Path:
    """A closed ring of `ORBIT_VIEWS` cameras around the same objects, under the same lightings.

    A second `render-multiview` of the held-out objects with `--layout orbit` (all views in its
    training split, in ring order) and the same seed, envmap pool and lighting count: gaffer-data
    draws each object's lightings (map, flip, yaw) from (seed, object id) alone, so the orbit is lit
    exactly as the sphere-layout views are (checked per object by `orbit_views`). Made once, reused.
    """
    renders(NUM_OBJECTS, split)  # the held-out objects and maps it copies
    root = split.data_root()
    out = root / "orbit"
    objects = sorted(
        p for p in (out / "objects").glob("*") if (p / "transforms_train.json").is_file()
    )
    if (out / "dataset.json").is_file() and len(objects) >= NUM_OBJECTS:
        return out
    held = root / "held"
    common.log(
        f"  rendering a {ORBIT_VIEWS}-frame orbit of {NUM_OBJECTS} objects into {out} (once)"
    )
    subprocess.run(
        [
            str(Path(sys.executable).parent / "gaffer-data"),
            "render-multiview",
            *("--objects", str(held / "objects"), "--envmaps", str(held / "envmaps")),
            *("--out", str(out), "--lightings", str(1 + len(split.targets))),
            *("--resolution", str(RESOLUTION), "--samples", str(SAMPLES)),
            *("--seed", str(split.render_seed), "--workers", "1"),
            *("--train-views", str(ORBIT_VIEWS), "--test-views", "0"),
            *("--layout", "orbit", "--orbit-elevation", str(ORBIT_ELEVATION_DEG), "--no-progress"),
        ],
        check=True,
    )
    return out


def orbit_views(orbit_folder: Path, scene: Any, lighting_index: int) -> Any:
    """The orbit's frames under one lighting, in ring order (a `ViewSet`).

    Raises:
        RuntimeError: the orbit render's lighting draws differ from `scene`'s (a different pool,
            seed or gaffer-data version), so its frames would not show the same lighting.
    """
    from gaffer_nerf import read_gaffer_data_object

    probe = read_gaffer_data_object(orbit_folder)

    def draws(s: Any) -> list[tuple[Any, ...]]:
        return [(x.lighting_index, x.envmap, x.flip, x.yaw_step, x.num_steps) for x in s.lightings]

    if draws(probe) != draws(scene):
        raise RuntimeError(
            f"{orbit_folder}: its lighting draws differ from the sphere-layout render's; delete "
            f"{orbit_folder.parent.parent} and rerun to render it again"
        )
    views = read_gaffer_data_object(orbit_folder, lighting_index=lighting_index).train
    centre = views.cameras.c2w_opencv[:, :3, 3]
    return views.select(torch.argsort(torch.atan2(centre[:, 1], centre[:, 0])).tolist())


def lighting_indices(scene: Any) -> dict[str, int]:
    """HDRI name -> the object's lighting index (gaffer-data draws the order per object)."""
    return {li.envmap: li.lighting_index for li in scene.lightings}


# ---------------------------------------------------------------------------------------- scoring


def scores(report: Any) -> dict[str, float | None]:
    obj, al = report.mean_object_raw, report.mean_object_aligned
    return {
        "psnr_object_db": round(float(obj.psnr), 3),
        "ssim_object": round(float(obj.ssim), 4),
        "stlpips_crop": None if obj.perceptual is None else round(float(obj.perceptual), 4),
        "psnr_object_aligned_db": round(float(al.psnr), 3),
        "psnr_full_frame_db": round(float(report.mean_raw.psnr), 3),
    }


def orbit_flicker(field: Any, orbit: Any) -> dict[str, float]:
    """The field rendered along the orbit, scored for flicker against the Cycles orbit."""
    from gaffer_nerf.evaluate import render_views
    from gaffer_nerf.flicker import temporal_flicker

    with torch.no_grad():
        seq = render_views(field, orbit.cameras)
    gt = orbit.rgb_srgb.permute(0, 3, 1, 2).contiguous()
    rep = temporal_flicker(seq, gt, orbit.alpha, closed=True)
    return {
        "orbit_flicker": round(rep.flicker, 5),
        "orbit_energy_ratio": round(rep.energy_ratio, 3),
    }


def _to_u8(img: torch.Tensor) -> np.ndarray:
    return (img.clamp(0, 1).permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8)


# ---------------------------------------------------------------------------------------- run


def configs(quick: bool, seed: int) -> tuple[Any, Any]:
    """The fit and relight configs every real-render benchmark runs: the tiny presets with the
    sizing rule, this benchmark's iteration counts (`QUICK` ones with `quick`) and `seed`."""
    from gaffer_nerf import fit_preset, relight_preset

    base = fit_preset("tiny")
    fit_cfg = dataclasses.replace(
        base,
        iterations=QUICK["fit"] if quick else FIT_ITERATIONS,
        seed=seed,
        sizing=dataclasses.replace(base.sizing, mode="footprint"),
    )
    s1_iters = QUICK["stage1"] if quick else STAGE1_ITERATIONS
    s2_iters = QUICK["stage2"] if quick else STAGE2_ITERATIONS
    rcfg = relight_preset("tiny")
    if rcfg.stage1 is None or rcfg.stage2 is None:
        raise RuntimeError("relight_preset('tiny') lost a stage")
    rcfg = dataclasses.replace(
        rcfg,
        seed=seed,
        stage1=dataclasses.replace(rcfg.stage1, iterations=s1_iters),
        stage2=dataclasses.replace(
            rcfg.stage2, iterations=s2_iters, lr_gamma=0.1 ** (1.0 / max(s2_iters, 1))
        ),
    )
    return fit_cfg, rcfg


def run(quick: bool, seed: int) -> dict[str, Any]:
    from gaffer_diffusion import RelightPipeline, RuntimeConfig
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual
    from gaffer_nerf import (
        evaluate_field,
        fit_tensorf,
        load_perceptual_loss,
        read_gaffer_data_object,
        relight_field,
    )
    from gaffer_nerf.data import load_lighting_envmap
    from gaffer_nerf.guidance import DiffusionGuide
    from gaffer_nerf.guidance.model import load_relighting_model
    from gaffer_nerf.sizing import budget_side

    n_objects = QUICK["objects"] if quick else NUM_OBJECTS
    targets = TARGET_HDRIS[: QUICK["targets"]] if quick else TARGET_HDRIS

    t0 = time.perf_counter()
    root = renders(n_objects)
    orbit_root = orbit_renders()
    render_s = time.perf_counter() - t0
    folders = sorted(
        p for p in (root / "objects").iterdir() if (p / "transforms_test.json").is_file()
    )[:n_objects]

    fit_cfg, rcfg = configs(quick, seed)

    t0 = time.perf_counter()
    loaded = load_relighting_model(None)  # what `gaffer-nerf relight` does without --checkpoint
    guide = DiffusionGuide(
        RelightPipeline(loaded.model, RuntimeConfig(device="cpu", dtype="float32")),
        rcfg.diffusion,
        loaded.suggested,
    )
    perceptual_loss = load_perceptual_loss()
    try:
        metric: Any = load_perceptual()
    except MetricUnavailableError as exc:
        common.log(f"  ST-LPIPS unavailable ({exc}); scored without it")
        metric = None
    load_s = time.perf_counter() - t0
    common.log(f"  model: {loaded.describe()}")
    common.log(f"  resolved sampling: {guide.sampling}")
    guide_whole = DiffusionGuide(
        guide.pipeline,
        dataclasses.replace(rcfg.diffusion, object_fraction="whole"),
        loaded.suggested,
    )
    guide_per_view = DiffusionGuide(
        guide.pipeline, dataclasses.replace(rcfg.diffusion, shared_noise=False), loaded.suggested
    )

    pairs: list[dict[str, Any]] = []
    fits: list[dict[str, Any]] = []
    strips: list[np.ndarray] = []
    for folder in folders:
        probe = read_gaffer_data_object(folder)
        idx = lighting_indices(probe)
        scene = read_gaffer_data_object(folder, lighting_index=idx[INPUT_HDRI])
        assert scene.test is not None
        t0 = time.perf_counter()
        fit = fit_tensorf(scene.train, fit_cfg)
        fit_wall = time.perf_counter() - t0
        fit_rep, _ = evaluate_field(fit.field, scene.test, perceptual=metric)
        fr = fit.report
        fits.append(
            {
                "object": folder.name,
                "lightings": {k: v for k, v in sorted(idx.items(), key=lambda kv: kv[1])},
                "seconds": round(fr.seconds, 3),
                "wall_seconds": round(fit_wall, 3),
                "iterations": fr.iterations_run,
                "final_grid": list(fr.final_grid),
                "grid_mib": round(fr.grid_bytes / 2**20, 4),
                "budget_side": round(float(budget_side(fit_cfg) or 0.0), 2),
                "input_lighting_test": scores(fit_rep),
            }
        )
        common.log(
            f"  {folder.name}: fit {fr.seconds:.1f} s, grid {'x'.join(map(str, fr.final_grid))}, "
            f"test under {INPUT_HDRI}: {fit_rep.mean_object_raw.psnr:.2f} dB (object)"
        )
        for target in targets:
            li = idx[target]
            gt_scene = read_gaffer_data_object(folder, lighting_index=li)
            gt = gt_scene.test
            assert gt is not None
            env = load_lighting_envmap(scene.lighting(li), root.parent / "held" / "envmaps")
            row: dict[str, Any] = {"object": folder.name, "target": target, "variants": {}}
            renders_of: dict[str, torch.Tensor] = {}
            orbit = orbit_views(orbit_root / "objects" / folder.name, scene, li)
            rep, pred = evaluate_field(fit.field, gt, perceptual=metric)
            row["variants"]["unrelit"] = {
                **scores(rep),
                **orbit_flicker(fit.field, orbit),
                "phase_seconds": {},
                "seconds": 0.0,
            }
            renders_of["unrelit"] = pred
            relit_views = None
            relit_s = 0.0
            for variant in VARIANTS[1:]:
                cfg = rcfg.with_ablation(ABLATION_OF[variant])  # type: ignore[arg-type]
                if cfg.stage2 is not None and cfg.stage2.loss == "sds":
                    # the SDS baselines keep the learning rates they were measured with before
                    # (the paper's; also the validation sweep's SDS row): the quarter rates were
                    # chosen for the guidance loss only
                    cfg = dataclasses.replace(cfg, stage2=dataclasses.replace(cfg.stage2, **SDS_LR))
                views, oracle, g = relit_views, None, guide
                if variant == "full-whole":  # its own relit views, from whole frames
                    views, g = None, guide_whole
                elif variant == "full-per-view":  # its own relit views, a noise per view
                    views, g = None, guide_per_view
                elif variant == "stage1-oracle":
                    views, oracle = None, gt_scene.train.rgb_srgb.permute(0, 3, 1, 2).contiguous()
                elif cfg.stage1 is None:
                    views = None
                res = relight_field(
                    fit.field,
                    scene.train,
                    env,
                    g,
                    cfg,
                    perceptual_loss,
                    relit_views=views,
                    stage1_targets=oracle,
                )
                r = res.report
                if variant == "stage1":
                    relit_views, relit_s = res.relit_views, r.relight_views_seconds
                uses_relit = cfg.stage1 is not None and variant != "stage1-oracle"
                phases = {
                    "cache": round(r.cache_seconds, 3),
                    "encode": round(r.encode_seconds, 3),
                    "relit views": round(
                        r.relight_views_seconds
                        if variant in ("full-whole", "full-per-view")
                        else (relit_s if uses_relit else 0.0),
                        3,
                    ),
                    "stage 1": round(r.stage1.seconds if r.stage1 else 0.0, 3),
                    "stage 2": round(r.stage2.seconds if r.stage2 else 0.0, 3),
                }
                rep, pred = evaluate_field(res.field, gt, perceptual=metric)
                row["variants"][variant] = {
                    **scores(rep),
                    **orbit_flicker(res.field, orbit),
                    "phase_seconds": phases,
                    "seconds": round(sum(phases.values()), 3),
                    "stage2_final_loss": None
                    if r.stage2 is None
                    else round(float(r.stage2.losses[-1]), 5),
                }
                renders_of[variant] = pred
            if relit_views is not None:
                row["relit_views_mean_srgb"] = round(float(relit_views.mean()), 4)
                row["train_target_mean_srgb"] = round(float(gt_scene.train.rgb_srgb.mean()), 4)
            pairs.append(row)
            v = row["variants"]
            common.log(
                f"  {folder.name} -> {target}: object PSNR "
                + ", ".join(f"{k} {v[k]['psnr_object_db']:.2f}" for k in VARIANTS)
                + f" dB; full {v['full']['seconds']:.1f} s"
            )
            # one test view per variant beside its ground truth (results/runs, git-ignored)
            strips.append(
                np.concatenate(
                    [_to_u8(renders_of[k][0]) for k in VARIANTS]
                    + [_to_u8(gt.rgb_srgb[0].permute(2, 0, 1))],
                    axis=1,
                )
            )
    if strips:
        from PIL import Image

        common.RUNS.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.concatenate(strips, axis=0)).save(common.RUNS / f"{NAME}_views.png")

    s = guide.sampling
    return {
        "config": {
            "quick": quick,
            "seed": seed,
            "objects": [f.name for f in folders],
            "objects_from": f"gaffer-data recipe --procedural {NUM_OBJECTS} --seed {OBJECT_SEED}",
            "render": (
                f"gaffer-data render-multiview, {RESOLUTION} px, {SAMPLES} spp + denoiser, "
                f"--seed {RENDER_SEED}, {TRAIN_VIEWS} train + {TEST_VIEWS} test views (sphere layout)"
            ),
            "input_lighting": INPUT_HDRI,
            "target_lightings": list(targets),
            "target_lightings_are": "gaffer-tiny's test-split HDRIs (model card)",
            "model": loaded.name,
            "model_source": str(loaded.source),
            # which weights: release, shipped or not, sha256 of every weights file
            "model_provenance": common.model_provenance(Path(str(loaded.source)))
            if Path(str(loaded.source)).joinpath("gaffer_model.json").is_file()
            else None,
            "sampling": {
                "num_inference_steps": s.num_inference_steps,
                "guidance_scale": s.guidance_scale,
                "average_samples": s.average_samples,
                "mirror_average": s.mirror_average,
                "compat": s.compat,
                "latent_mode": s.latent_mode,
                "shared_noise": s.shared_noise,
                "object_fraction": s.object_fraction,
                "source": loaded.suggested.source,
            },
            "fit": (
                f"fit_preset('tiny'), {fit_cfg.iterations} iterations of {fit_cfg.batch_rays} rays, "
                "sizing rule: GridSizingConfig(mode='footprint') (footprint + iteration budget)"
            ),
            "stage1_iterations": rcfg.stage1.iterations,
            "stage1_batch_rays": rcfg.stage1.batch_rays,
            "stage2_iterations": rcfg.stage2.iterations,
            "stage2_lr_gamma": round(rcfg.stage2.lr_gamma, 5),
            "stage2_t_schedule": rcfg.stage2.t_schedule,
            "stage2_settings": {
                k: getattr(rcfg.stage2, k)
                for k in (
                    "t_start",
                    "t_end",
                    "l1_weight",
                    "perceptual_weight",
                    "lr_grid",
                    "lr_network",
                )
            },
            "sds_variants_learning_rates": SDS_LR,
            "stage2_settings_from": (
                "relight_preset('tiny'), chosen on the validation split "
                "(nerf_sweep.py run stage2, results/nerf_stage2_val.json)"
            ),
            "stage1_targets": {
                "target_detail": rcfg.stage1.target_detail,
                "transfer_radius_px": rcfg.stage1.transfer_radius_px,
                "from": "relight_preset('tiny'), chosen on the validation split "
                "(nerf_sweep.py run stage1, results/nerf_stage1_val.json)",
            },
            "shared_noise_from": "relight_preset('tiny'), chosen on the validation split "
            "(nerf_sweep.py run noise, results/nerf_noise_val.json)",
            "sds_guidance_scale": guide.sds_guidance(rcfg.stage2),
            "perceptual_metric": None if metric is None else metric.name,
            "stage2_perceptual_loss": perceptual_loss.name,
        },
        "seconds": {"renders_or_cache_check": round(render_s, 3), "load_model": round(load_s, 3)},
        "fits": fits,
        "pairs": pairs,
    }


def summarise(result: dict[str, Any]) -> dict[str, Any]:
    pairs = result["pairs"]
    keys = (
        "psnr_object_db",
        "ssim_object",
        "stlpips_crop",
        "psnr_object_aligned_db",
        "psnr_full_frame_db",
        "orbit_flicker",
        "orbit_energy_ratio",
        "seconds",
    )
    out: dict[str, Any] = {}
    for k in VARIANTS:
        row: dict[str, Any] = {}
        for key in keys:
            vals = [p["variants"][k][key] for p in pairs]
            row[key] = None if any(v is None for v in vals) else round(float(np.mean(vals)), 4)
        phases = [p["variants"][k]["phase_seconds"] for p in pairs]
        row["phase_seconds"] = {
            ph: round(float(np.mean([p.get(ph, 0.0) for p in phases])), 3)
            for ph in ("cache", "encode", "relit views", "stage 1", "stage 2")
        }
        out[k] = row
    fits = result["fits"]
    out["fit_seconds_mean"] = round(float(np.mean([f["seconds"] for f in fits])), 3)

    def wins(a: str, b: str, key: str, higher: bool = True) -> int:
        n = 0
        for p in pairs:
            x, y = p["variants"][a][key], p["variants"][b][key]
            if x is not None and y is not None and ((x > y) if higher else (x < y)):
                n += 1
        return n

    out["pairs"] = len(pairs)
    out["full_beats"] = {
        other: {
            "psnr_object_pairs": wins("full", other, "psnr_object_db"),
            "stlpips_crop_pairs": wins("full", other, "stlpips_crop", higher=False),
            "mean_psnr_object_gain_db": round(
                out["full"]["psnr_object_db"] - out[other]["psnr_object_db"], 3
            ),
        }
        for other in ("unrelit", "sds-only", "stage1", "sds-stage2", "full-whole", "full-per-view")
    }
    f, u, sds = out["full"], out["unrelit"], out["sds-only"]
    out["full_beats_unrelit_and_sds_on_mean_psnr"] = bool(
        f["psnr_object_db"] > u["psnr_object_db"] and f["psnr_object_db"] > sds["psnr_object_db"]
    )
    return out


# ---------------------------------------------------------------------------------------- output


def plot(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = payload["summary"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    for ax, key, name in (
        (axes[0], "psnr_object_db", "object-mask PSNR (dB, higher is better)"),
        (axes[1], "stlpips_crop", "ST-LPIPS on the object crop (shift-tolerant; lower is better)"),
    ):
        for k in VARIANTS:
            y = s[k][key]
            if y is None:
                continue
            marker = "*" if k == "full" else ("D" if k == "stage1-oracle" else "o")
            ax.plot(
                s[k]["seconds"],
                y,
                marker,
                color=COLOURS[k],
                markersize=12 if k == "full" else 9,
                label=LABELS[k],
                markerfacecolor="none" if k == "stage1-oracle" else COLOURS[k],
            )
            # the individual pairs, faint
            xs = [p["variants"][k]["seconds"] for p in payload["pairs"]]
            ys = [p["variants"][k][key] for p in payload["pairs"]]
            ax.scatter(xs, ys, s=12, color=COLOURS[k], alpha=0.3)
        ax.set_xlabel(
            f"relighting seconds per object and lighting (after a {s['fit_seconds_mean']:.0f} s fit)"
        )
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="best")
    c = payload["config"]
    fig.suptitle(
        f"gaffer-nerf + gaffer-tiny on {len(c['objects'])} unseen objects, {c['input_lighting']} -> "
        f"{'/'.join(c['target_lightings'])} ({s['pairs']} pairs, big markers = means)\n"
        f"{common.short_device(payload['machine'])}",
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def markdown(payload: dict[str, Any]) -> str:
    s, c, m = payload["summary"], payload["config"], payload["machine"]
    lines = [
        f"Measured {m['date_utc']} on {m['device']}, torch {m['torch']} ({m['torch_threads']} "
        f"threads); load average {m['load_average_start'][0]:.1f} at start, "
        f"{m['load_average_end'][0]:.1f} at end. {len(c['objects'])} unseen procedural objects, "
        f"{c['input_lighting']} -> {' / '.join(c['target_lightings'])} ({s['pairs']} pairs), "
        f"5 test views each; gaffer-tiny sampled with its own setting; fit "
        f"{s['fit_seconds_mean']:.0f} s per object (not in the seconds below).",
        "",
        "| variant | object PSNR (dB) | object SSIM | ST-LPIPS crop | aligned PSNR (dB) | "
        "full-frame PSNR (dB) | orbit flicker (energy ratio) | relight s | "
        "relit views / stage 1 / stage 2 s |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for k in VARIANTS:
        r = s[k]
        ph = r["phase_seconds"]
        lp = "-" if r["stlpips_crop"] is None else f"{r['stlpips_crop']:.4f}"
        lines.append(
            f"| {LABELS[k]} | {r['psnr_object_db']:.2f} | {r['ssim_object']:.4f} | {lp} | "
            f"{r['psnr_object_aligned_db']:.2f} | {r['psnr_full_frame_db']:.2f} | "
            f"{r['orbit_flicker']:.4f} ({r['orbit_energy_ratio']:.2f}) | {r['seconds']:.1f} | {ph['relit views']:.1f} / {ph['stage 1']:.1f} / "
            f"{ph['stage 2']:.1f} |"
        )
    fb = s["full_beats"]
    lines += [
        "",
        f"Full vs unrelit: {fb['unrelit']['mean_psnr_object_gain_db']:+.2f} dB, better PSNR on "
        f"{fb['unrelit']['psnr_object_pairs']}/{s['pairs']} pairs; full vs SDS only: "
        f"{fb['sds-only']['mean_psnr_object_gain_db']:+.2f} dB "
        f"({fb['sds-only']['psnr_object_pairs']}/{s['pairs']}); full vs Stage 1 only: "
        f"{fb['stage1']['mean_psnr_object_gain_db']:+.2f} dB "
        f"({fb['stage1']['psnr_object_pairs']}/{s['pairs']}). The oracle row is Stage 1 fitted to "
        "Cycles renders of the training views under the target (a ceiling, not a method). Orbit "
        "flicker: `gaffer_nerf.flicker.temporal_flicker` along a closed 16-frame Cycles orbit under "
        "the target (mean |frame-to-frame change - the truth's| in the object mask, sRGB; 0 = none; "
        "energy ratio > 1: the sequence changes more than the truth).",
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    args = common.parse_args(__doc__.split("\n")[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    import gaffer_nerf

    meta["gaffer_nerf"] = gaffer_nerf.__version__
    t0 = time.perf_counter()
    result = run(args.quick, args.seed)
    payload = {"name": NAME, "machine": meta, **result}
    payload["summary"] = summarise(payload)
    payload["seconds"]["total_wall"] = round(time.perf_counter() - t0, 1)
    for path in common.write_results(NAME, payload, plot(payload), args.update_baseline):
        common.log(f"wrote {path}")
    table = markdown(payload)
    if args.update_baseline and not common.update_readme(NAME, table):
        common.log("  (benchmarks/README.md has no nerf_real markers; table not written there)")
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
