"""Where the shipped gaffer-tiny's raw object PSNR loses to its channel-aligned one: exposure or tint.

A single photo does not say how bright its light was: a dark object under a bright map and a bright
object under a dim map give the same picture, so the relit object's overall level is a guess that
the model learns as a prior over its training renders (the scale ambiguity the paper's per-channel
rescaling removes, Sec. 5.1). This splits the gap between the two object scores of
`gaffer-diffusion evaluate` on the validation split (every pair):

- `raw`: display-space PSNR over the object mask, as evaluate reports it;
- `exposure`: after one gain for all three channels (mean luminance over the mask matched to the
  truth's), which removes only the overall level;
- `aligned`: after one gain per channel (`gaffer_diffusion.metrics.channel_align`, evaluate's
  aligned score), which also removes the tint;

for the model and for the unrelit input, and the level error in stops
(log2 of the truth's mean object luminance over the prediction's), by input map and by target map.
It then asks whether that error could be predicted from what is known at run time (the input's and
the prediction's mean levels, the target map's mean, peak and upper-hemisphere radiance): a ridge
regression cross-validated by object (4 folds, no object scored by a fit that saw it); the
correction it predicts is applied and scored (`calibrated`).

Predictions come from `gaffer-diffusion evaluate --save-predictions` with the model card's settings
and are cached under results/runs/exposure_gap/ (git-ignored). Validation only: no choice is made here,
and the test split is not read.

Run: `flock /tmp/gaffer-cpu.lock python benchmarks/bench_exposure_gap.py --threads 2
[--split DIR] [--update-baseline]`; `--quick` runs it on `bench_reshade.py`'s tiny render instead
(2 objects, made once with bpy), to check the script, not to measure.
"""

import json
import math
import os
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
import torch

from gaffer_diffusion.models.pixel import LUMA_WEIGHTS

NAME = "exposure_gap"
DEFAULT_SPLIT = common.RESULTS.parent.parent / "packages/gaffer-diffusion/runs/data/render_val05"
LUMA = np.array(LUMA_WEIGHTS, np.float32)
FOLDS = 4
RIDGE = 1e-3


@dataclass(frozen=True)
class PairScores:
    """One pair's object PSNRs (dB) and level error (stops) for one prediction."""

    raw: float
    exposure: float
    aligned: float
    level_error_stops: float


def _split_arg() -> tuple[Path, list[str]]:
    argv = sys.argv[1:]
    if "--split" in argv:
        i = argv.index("--split")
        if i + 1 >= len(argv):
            raise SystemExit("--split needs a folder: a gaffer-data render, e.g. render_val05.")
        split = Path(argv[i + 1])
        return split, argv[:i] + argv[i + 2 :]
    return DEFAULT_SPLIT, argv


def _predictions(split: Path, threads: int, name: str) -> Path:
    out = common.RUNS / NAME / name
    done = out / "DONE"
    if done.is_file():
        return out
    exe = Path(sys.executable).parent / "gaffer-diffusion"
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    out.mkdir(parents=True, exist_ok=True)
    cmd = [str(exe), "evaluate", "--dataset", str(split), "--save-predictions", str(out / "pred"),
           "--no-perceptual", "--json", str(out / "evaluate.json")]  # fmt: skip
    common.log("  " + " ".join(cmd))
    run = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if run.returncode != 0:
        raise SystemExit(f"evaluate exited {run.returncode}: {run.stderr.strip()[-600:]}")
    done.write_text(" ".join(cmd) + "\n")
    return out


def _mean_luma(image: np.ndarray, mask: np.ndarray) -> float:
    """Mean Rec. 709 luminance of `image` (display values) weighted by `mask`."""
    mean = (image * mask[..., None]).sum((0, 1)) / max(float(mask.sum()), 1e-6)
    return float(mean @ LUMA)


def _scores(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> PairScores:
    from gaffer_diffusion.metrics import channel_align, masked_psnr

    p = torch.from_numpy(pred).permute(2, 0, 1)[None]
    t = torch.from_numpy(truth).permute(2, 0, 1)[None]
    m = torch.from_numpy(mask.astype(np.float32))[None, None]
    gain = _mean_luma(truth, mask) / max(_mean_luma(pred, mask), 1e-6)
    return PairScores(
        raw=float(masked_psnr(p, t, m)[0]),
        exposure=float(masked_psnr((p * gain).clamp(0, 1), t, m)[0]),
        aligned=float(masked_psnr(channel_align(p, t, m), t, m)[0]),
        level_error_stops=math.log2(max(gain, 1e-6)),
    )


def _level(image: np.ndarray, mask: np.ndarray) -> float:
    """log2 of the mean luminance over the mask (display values)."""
    return math.log2(max(_mean_luma(image, mask), 1e-4))


def _map_features(path: Path, cache: dict[Path, list[float]]) -> list[float]:
    """log2 of the map's solid-angle mean, peak and upper-hemisphere mean luminance."""
    if path not in cache:
        from gaffer_envmap import read_envmap
        from gaffer_envmap.conventions import row_solid_angle

        env = read_envmap(path)
        lum = np.asarray(env.radiance_linear, np.float64) @ LUMA
        omega = row_solid_angle(env.height, env.width, env.alignment)  # [He], sums to 4 pi
        top = env.height // 2
        mean = float(omega @ lum.sum(1) / (4 * np.pi))
        upper = float(omega[:top] @ lum[:top].sum(1) / (omega[:top].sum() * env.width))
        cache[path] = [math.log2(mean + 1e-6), math.log2(float(lum.max()) + 1e-6),
                       math.log2(upper + 1e-6)]  # fmt: skip
    return cache[path]


def main() -> None:
    split, argv = _split_arg()
    args = common.parse_args(__doc__ or "", argv)
    threads = common.set_threads(args.threads or 2)
    name, cache = NAME, split.name
    if args.quick:
        from bench_reshade import quick_split

        split, name, cache = quick_split(), f"{NAME}_quick", "quick"
    if not (split / "dataset.json").is_file():
        raise SystemExit(
            f"--split {split} is not a gaffer-data render (no dataset.json): render the validation "
            "split as the gaffer-tiny model card says, or pass --quick."
        )
    from PIL import Image

    from gaffer_diffusion.evaluation.images import pair_crop_box, read_mask, read_rgba_on_white
    from gaffer_diffusion.evaluation.pairs import dataset_pairs

    run = _predictions(split, threads, cache)
    evaluate = json.loads((run / "evaluate.json").read_text())
    fraction = 0.75  # gaffer-tiny's framing (its suggested `object_fraction`), as evaluate frames
    pairs = dataset_pairs(split)
    manifests: dict[str, Any] = {}
    maps: dict[Path, list[float]] = {}
    rows = []
    for p in pairs:
        if p.mask is None:
            raise SystemExit(f"pair {p.name} has no mask: this benchmark scores over the object.")
        box = pair_crop_box(p, fraction)
        truth, _ = read_rgba_on_white(p.target_image, 128, box)
        inp, _ = read_rgba_on_white(p.input_image, 128, box)
        mask = read_mask(p.mask, 128, box).astype(np.float32)  # alpha weights, as evaluate scores
        pred = np.asarray(Image.open(run / "pred" / f"{p.name}.png").convert("RGB"), np.float32)
        pred = pred / 255.0
        if p.object_id not in manifests:
            manifests[p.object_id] = json.loads(
                (split / "objects" / p.object_id / "manifest.json").read_text()
            )
        view = manifests[p.object_id]["views"][p.view_index]
        model, unrelit = _scores(pred, truth, mask), _scores(inp, truth, mask)
        features = [
            1.0,
            _level(inp, mask),
            _level(pred, mask),
            *_map_features(p.lighting.source, maps),
        ]
        rows.append(
            {
                "pair": p.name,
                "object": p.object_id,
                "input_map": view["lit"][0]["envmap"]["name"],
                "target_map": view["lit"][p.target_lighting]["envmap"]["name"],
                "model": model,
                "input": unrelit,
                "features": features,
                "pred": pred,
                "truth": truth,
                "mask": mask,
            }
        )
    # cross-validated calibration of the level error from run-time statistics
    x = np.array([r["features"] for r in rows], np.float64)
    y = np.array([r["model"].level_error_stops for r in rows], np.float64)
    objects = sorted({r["object"] for r in rows})
    predicted = np.zeros_like(y)
    for k in range(FOLDS):
        held = np.isin([r["object"] for r in rows], objects[k::FOLDS])
        a = x[~held]
        coef = np.linalg.solve(a.T @ a + RIDGE * np.eye(a.shape[1]), a.T @ y[~held])
        predicted[held] = x[held] @ coef
    from gaffer_diffusion.metrics import masked_psnr

    calibrated = []
    for r, stops in zip(rows, predicted, strict=True):
        p = torch.from_numpy(np.clip(r["pred"] * 2.0**stops, 0, 1)).permute(2, 0, 1)[None]
        t = torch.from_numpy(r["truth"]).permute(2, 0, 1)[None]
        m = torch.from_numpy(r["mask"])[None, None]
        calibrated.append(float(masked_psnr(p, t, m)[0]))

    def mean(who: str, what: str) -> float:
        return round(float(np.mean([getattr(r[who], what) for r in rows])), 3)

    def by(key: str) -> dict[str, Any]:
        groups: dict[str, list[float]] = defaultdict(list)
        for r in rows:
            groups[r[key]].append(r["model"].level_error_stops)
        return {
            k: {
                "pairs": len(v),
                "signed_stops": round(float(np.mean(v)), 3),
                "abs_stops": round(float(np.mean(np.abs(v))), 3),
            }
            for k, v in sorted(groups.items())
        }

    summary = {
        who: {
            "object_psnr_raw": mean(who, "raw"),
            "object_psnr_exposure_aligned": mean(who, "exposure"),
            "object_psnr_aligned": mean(who, "aligned"),
            "level_error_abs_stops_mean": round(
                float(np.mean([abs(r[who].level_error_stops) for r in rows])), 3
            ),
            "level_error_abs_stops_median": round(
                float(np.median([abs(r[who].level_error_stops) for r in rows])), 3
            ),
            "level_error_signed_stops_mean": mean(who, "level_error_stops"),
        }
        for who in ("model", "input")
    }
    # the split must be scored exactly as evaluate scored it, or the gap below means nothing
    for key, ours in (
        ("mean_object_raw", "object_psnr_raw"),
        ("mean_object_aligned", "object_psnr_aligned"),
    ):
        theirs = evaluate["metrics"][key]["psnr"]
        if abs(theirs - summary["model"][ours]) > 0.01:
            raise SystemExit(
                f"{ours} {summary['model'][ours]} differs from evaluate's {theirs:.3f}"
            )
    summary["model"]["object_psnr_calibrated"] = round(float(np.mean(calibrated)), 3)
    summary["model"]["calibration_abs_stops_mean"] = round(float(np.mean(np.abs(y - predicted))), 3)
    payload = {
        **common.model_result_header(
            name, __doc__, split, split=f"{split.name} (validation; every pair)"
        ),
        "evaluate_command": (run / "DONE").read_text().strip(),
        "pairs": len(rows),
        "summary": summary,
        "gap_db": {
            "exposure": round(
                summary["model"]["object_psnr_exposure_aligned"]
                - summary["model"]["object_psnr_raw"],
                3,
            ),
            "tint": round(
                summary["model"]["object_psnr_aligned"]
                - summary["model"]["object_psnr_exposure_aligned"],
                3,
            ),
        },
        "map_mean_luminance": {
            path.stem: round(2.0 ** feats[0], 3) for path, feats in sorted(maps.items())
        },
        "level_error_by_input_map": by("input_map"),
        "level_error_by_target_map": by("target_map"),
        "calibration": {
            "features": [
                "1",
                "log2 input level",
                "log2 prediction level",
                "log2 target map mean",
                "log2 target map peak",
                "log2 target map upper-hemisphere mean",
            ],
            "folds_by_object": FOLDS,
            "ridge": RIDGE,
        },
        "machine": common.machine(threads),
    }
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    kinds = ("object_psnr_raw", "object_psnr_exposure_aligned", "object_psnr_aligned")
    labels = ("raw", "one gain\n(exposure)", "gain per channel\n(aligned)")
    pos = np.arange(len(kinds))
    for i, who in enumerate(("input", "model")):
        vals = [summary[who][k] for k in kinds]
        ax.bar(
            pos + (i - 0.5) * 0.38,
            vals,
            0.38,
            label="unrelit input" if who == "input" else "gaffer-tiny",
        )
    ax.axhline(summary["model"]["object_psnr_calibrated"], color="k", ls=":", lw=1,
               label="gaffer-tiny, level calibrated (CV)")  # fmt: skip
    ax.set_xticks(pos, labels)
    ax.set_ylim(10, max(summary["model"]["object_psnr_aligned"], 20) + 2)
    ax.set_ylabel("object PSNR (dB)")
    ax.set_title(f"Raw vs aligned gap, {split.name} ({len(rows)} pairs)")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    for path in common.write_results(name, payload, fig, args.update_baseline and not args.quick):
        common.log(f"wrote {path}")
    print(json.dumps({"summary": summary, "gap_db": payload["gap_db"]}))


if __name__ == "__main__":
    main()
