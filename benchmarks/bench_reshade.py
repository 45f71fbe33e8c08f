"""Re-shading, not recolouring: relighting quality vs training time and parameters, by where
the radiance hints' geometry comes from.

Each row is a model folder (a gaffer-tiny release or an exported training checkpoint) scored on a
gaffer-data render split with its own suggested sampling (`gaffer-diffusion evaluate`'s defaults for
it), over the object mask in display space: PSNR raw and channel-aligned, shift-tolerant LPIPS
(`stlpips-alex`, not standard LPIPS) on the object crop, and the share of pairs closer than the input,
beside the two baselines (the unrelit input, and the input channel-aligned to the target). The hint
geometry of a row is

- `dome`: a model trained with silhouette-dome normals (gaffer-tiny 0.4);
- `estimated`: a model trained with the learned normal estimator's normals (gaffer-tiny 0.5), as
  every user path runs it;
- `true`: the same model fed the render's true camera-frame normals (the oracle ceiling of better
  geometry for that model: it was not retrained on them).

Training time is the model's cumulative training seconds on 2 CPU cores (its model card), given per
row; parameters count the UNet plus the estimator where one is used. Every row's per-pair metrics go
to `results/reshade/<split>-<label>.json` with the sha256 of the UNet weights they measured.

    python benchmarks/bench_reshade.py --split DIR --row LABEL=MODEL_DIR,GEOMETRY,TRAIN_S [...]
        [--limit N] [--threads 2] [--update-baseline]

`--quick` scores the shipped gaffer-tiny on a few pairs of a tiny render (made here with bpy), to check
the plumbing.
"""

import argparse
import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import _common as common
import gaffer_tiny_card as card
import numpy as np
import torch

NAME = "reshade"
GEOMETRIES = ("dome", "estimated", "true")


@dataclass(frozen=True)
class Row:
    label: str
    model: Path | None  # None: the shipped gaffer-tiny
    geometry: str
    train_seconds: float


def _parse_row(text: str) -> Row:
    try:
        label, rest = text.split("=", 1)
        model, geometry, seconds = rest.split(",")
    except ValueError:
        raise SystemExit(
            f"--row {text!r}: expected LABEL=MODEL_DIR,GEOMETRY,TRAIN_SECONDS"
        ) from None
    if geometry not in GEOMETRIES:
        raise SystemExit(f"--row {text!r}: GEOMETRY must be one of {GEOMETRIES}")
    return Row(label, None if model == "shipped" else Path(model), geometry, float(seconds))


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _rounded(value: Any) -> Any:
    """Floats to 5 decimals: far below any difference a score can show (1e-5 dB), and the committed
    per-pair files shrink by half."""
    if isinstance(value, float):
        return round(value, 5)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_rounded(v) for v in value]
    return value


def _release_of(folder: Path) -> str:
    """`"gaffer-tiny 0.5"` from a model folder's manifest `release`, else "unreleased checkpoint"."""
    manifest = json.loads((folder / "gaffer_model.json").read_text())
    release = manifest.get("release")
    if not isinstance(release, dict):
        return "unreleased checkpoint"
    return f"{release.get('name')} {release.get('version')}"


def true_normals_reader(split: Path) -> Any:
    """`(pair, box, size) -> [3, size, size]` true camera-frame normals of the pair's input view."""
    from gaffer_data import read_object
    from gaffer_diffusion.training.normals import view_normals_cam

    cache: dict[tuple[str, int], Any] = {}

    def normals_of(pair: Any, box: Any, size: int) -> torch.Tensor:
        key = (pair.object_id, pair.view_index)
        if key not in cache:
            cache[key] = read_object(split / "objects" / pair.object_id)
        obj = cache[key]
        view = next(v for v in obj.views if v.index == pair.view_index)
        w2c = np.asarray(obj.poses().w2c_blender[view.index], dtype=np.float64)
        n = view_normals_cam(obj, view.area.normal, w2c, box, size)
        # where the pass has no surface (antialiased rim), face the camera like the hints' default
        flat = torch.tensor([0.0, 0.0, 1.0]).view(3, 1, 1)
        return torch.where(n.norm(dim=0, keepdim=True) > 0.5, n, flat)

    return normals_of


def evaluate_row(
    row: Row, split: Path, limit: int | None, out_dir: Path, stride: int = 1
) -> dict[str, Any]:
    from gaffer_diffusion.evaluation import (
        EnvmapLighting,
        dataset_pairs,
        evaluate_dataset,
        suggested_evaluation_config,
    )
    from gaffer_diffusion.geometry.estimator import shipped_normal_estimator_path
    from gaffer_diffusion.loading import load_pretrained
    from gaffer_diffusion.pipelines import RelightPipeline
    from gaffer_diffusion.pretrained import gaffer_tiny_path, load_gaffer_tiny
    from gaffer_diffusion.suggested import read_suggested_sampling

    folder = gaffer_tiny_path() if row.model is None else row.model
    model = load_gaffer_tiny().model if row.model is None else load_pretrained(row.model).model
    if row.geometry != "dome" and model.config.hint_geometry != "estimated":
        raise SystemExit(f"{row.label}: geometry {row.geometry} needs an estimated-geometry model")
    if row.geometry == "dome" and model.config.hint_geometry != "silhouette":
        raise SystemExit(f"{row.label}: geometry dome needs a silhouette-hint model")
    suggested = read_suggested_sampling(folder)
    # every `stride`-th pair: a spread subset of every object (validation sweeps); 1 = all
    pairs = dataset_pairs(split, limit=limit)[::stride]
    config = suggested_evaluation_config(suggested, seed=0, batch_size=8)
    weights = folder / "unet" / "diffusion_pytorch_model.safetensors"
    settings = {
        "label": row.label,
        "model": str(folder),
        # a released model's name and version (its manifest's "release"); an exported training
        # checkpoint has none and is labelled so, never as the shipped model
        "release": _release_of(folder),
        "unet_sha256": _sha256(weights),
        "hint_geometry": row.geometry,
        "split": str(split),
        "split_manifest_sha256": _sha256(split / "dataset.json"),
        "pair_stride": stride,
    }
    params = sum(p.numel() for p in model.unet.parameters())
    if model.config.hint_geometry == "estimated":
        from gaffer_diffusion.geometry.estimator import shipped_normal_estimator

        settings["normal_estimator_sha256"] = _sha256(
            shipped_normal_estimator_path() / "unet" / "diffusion_pytorch_model.safetensors"
        )
        if row.geometry == "estimated":
            params += sum(p.numel() for p in shipped_normal_estimator().parameters())
    normals_of = true_normals_reader(split) if row.geometry == "true" else None
    start = time.perf_counter()
    result = evaluate_dataset(
        RelightPipeline(model), pairs, config, settings=settings, normals_of=normals_of
    )
    seconds = time.perf_counter() - start
    out_dir.mkdir(parents=True, exist_ok=True)
    document = json.loads(result.to_json())
    # what it ran on and which code: a per-pair file stands alone as the source of a card's number
    document["machine"] = common.machine(torch.get_num_threads())
    # each pair's target map (file stem), so tables by target HDRI come from this file alone
    document["pair_target_envmap"] = {
        p.name: Path(p.lighting.source).stem if isinstance(p.lighting, EnvmapLighting) else None
        for p in pairs
    }
    (out_dir / f"{split.name}-{row.label}.json").write_text(
        json.dumps(_rounded(document), indent=1) + "\n"
    )
    return {
        "label": row.label,
        "hint_geometry": row.geometry,
        "train_seconds": row.train_seconds,
        "parameters": params,
        # means over the pairs with something to relight (an input identical to its target is left
        # out: gaffer_tiny_card.row_means), the numbers the model card shows
        **card.row_means(document),
        "eval_seconds": seconds,
        "release": settings["release"],
        "unet_sha256": settings["unet_sha256"],
        "split_manifest_sha256": settings["split_manifest_sha256"],
    }


def figure(rows: list[dict[str, Any]], split: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    colours = {"dome": "tab:blue", "estimated": "tab:orange", "true": "tab:green"}
    metrics = (
        ("object_psnr_raw", "input_object_psnr_raw", "object PSNR raw (dB)"),
        ("object_psnr_aligned", "input_object_psnr_aligned", "object PSNR channel-aligned (dB)"),
        ("object_stlpips", "input_object_stlpips", "ST-LPIPS on the object crop (lower is better)"),
    )
    for col, (key, base, title) in enumerate(metrics):
        for r_i, xkey in enumerate(("train_seconds", "parameters")):
            ax = axes[r_i][col]
            for geo in GEOMETRIES:
                pts = sorted((r[xkey], r[key]) for r in rows if r["hint_geometry"] == geo)
                if pts:
                    xs = [p[0] / (60.0 if xkey == "train_seconds" else 1e6) for p in pts]
                    ax.plot(xs, [p[1] for p in pts], "o-", color=colours[geo], label=f"{geo} hints")
            base_v = float(np.mean([r[base] for r in rows]))
            ax.axhline(base_v, color="grey", ls="--", label="unrelit input")
            if key == "object_psnr_raw":
                al = float(np.mean([r["input_object_psnr_aligned"] for r in rows]))
                ax.axhline(al, color="grey", ls=":", label="input channel-aligned")
            ax.set_xlabel("training time (min, 2 CPU cores)" if r_i == 0 else "parameters (M)")
            ax.set_title(title, fontsize=10)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle(f"gaffer-tiny re-shading on {split}: quality vs training time and parameters")
    fig.tight_layout()
    return fig


def quick_split() -> Path:
    """A tiny render (2 objects, 1 view, 3 lightings) under results/runs/, made once."""
    import subprocess

    root = common.RUNS / "reshade_quick"
    data = root / "render"
    if (data / "dataset.json").is_file():
        return data
    rec = root / "recipe"
    gd = [sys.executable, "-m", "gaffer_data.cli"]
    subprocess.run([*gd, "recipe", str(rec), "--procedural", "2", "--seed", "41"], check=True)
    objs = rec / "objects" / "procedural"
    subprocess.run(
        [
            *gd,
            "render",
            "--objects",
            str(objs),
            "--envmaps",
            str(rec / "envmaps"),
            "--out",
            str(data),
            "--views",
            "1",
            "--lightings",
            "3",
            "--resolution",
            "128",
            "--samples",
            "8",
            "--no-denoise",
            "--world-map-resolution",
            "64",
            "--view-transform",
            "Standard",
            "--seed",
            "0",
            "--workers",
            "1",
            "--no-progress",
        ],
        check=True,
    )
    return data


def _parameters(folder: Path, geometry: str) -> int:
    """Parameters a row runs with: its UNet, plus the normal estimator when its hints use one."""
    from gaffer_diffusion.loading import load_pretrained

    model = load_pretrained(folder).model
    params = sum(p.numel() for p in model.unet.parameters())
    if model.config.hint_geometry == "estimated" and geometry == "estimated":
        from gaffer_diffusion.geometry.estimator import shipped_normal_estimator

        params += sum(p.numel() for p in shipped_normal_estimator().parameters())
    return params


def replot(split_name: str, rows: list[Row]) -> int:
    """Rebuild the summary and chart of `split_name` from the committed per-pair files.

    A row's training seconds and parameters come from `--row` when given (its model folder is only
    read for its parameter count, nothing is evaluated), else from the existing summary."""
    summary_path = common.RESULTS / f"{NAME}_{split_name}.json"
    payload = (
        json.loads(summary_path.read_text())
        if summary_path.is_file()
        else {"machine": None, "split": split_name, "rows": [], "pair_stride": None}
    )
    payload["rebuilt_from_per_pair_files"] = True
    known = {r["label"]: r for r in payload["rows"]}
    for row in rows:
        if row.model is None:
            from gaffer_diffusion.pretrained import gaffer_tiny_path

            folder = gaffer_tiny_path()
        else:
            folder = row.model
        known[row.label] = {
            "label": row.label,
            "hint_geometry": row.geometry,
            "train_seconds": row.train_seconds,
            "parameters": _parameters(folder, row.geometry),
        }
    out = []
    for label, entry in known.items():
        path = common.RESULTS / NAME / f"{split_name}-{label}.json"
        if not path.is_file():
            raise SystemExit(f"--replot: no per-pair file {path} for row {label!r}")
        doc = json.loads(path.read_text())
        entry.update(card.row_means(doc))
        for key in ("release", "unet_sha256", "split_manifest_sha256", "pair_stride"):
            entry[key] = doc["settings"].get(key)
        # each row's machine as its per-pair file recorded it (files written before the machine was
        # recorded have none, and the summary says so rather than guess)
        entry["machine"] = doc.get("machine")
        out.append(entry)
    payload["rows"] = out
    if payload["machine"] is None:
        payload["machine"] = next((r["machine"] for r in out if r["machine"]), None)
    summary_path.write_text(json.dumps(payload, indent=2, sort_keys=False) + "\n")
    figure(out, split_name).savefig(summary_path.with_suffix(".png"), dpi=120, bbox_inches="tight")
    print(f"rewrote {summary_path} and its chart from {common.RESULTS / NAME}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", type=Path, help="a gaffer-data render split")
    parser.add_argument(
        "--row", action="append", default=[], help="LABEL=MODEL_DIR,GEOMETRY,TRAIN_S"
    )
    parser.add_argument("--limit", type=int, default=None, help="pairs per row (default: all)")
    parser.add_argument("--stride", type=int, default=1, help="score every N-th pair (1: all)")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--update-baseline", action="store_true")
    parser.add_argument(
        "--replot",
        action="store_true",
        help="rebuild results/reshade_<split>.json and its chart from the committed per-pair files "
        "(no model runs; training seconds and parameters from --row, else kept from the summary)",
    )
    args = parser.parse_args(argv)
    if args.replot:
        if args.split is None:
            parser.error("--replot needs --split")
        return replot(args.split.name, [_parse_row(r) for r in args.row])
    threads = common.set_threads(args.threads)
    if args.quick:
        split, rows, limit = quick_split(), [Row("shipped", None, "estimated", 0.0)], 4
    else:
        if args.split is None or not args.row:
            parser.error("pass --split and at least one --row (or --quick)")
        split, rows, limit = args.split, [_parse_row(r) for r in args.row], args.limit
    meta = common.machine(threads)
    out_dir = common.RESULTS / NAME if args.update_baseline else common.RUNS / NAME
    results = []
    for row in rows:
        res = evaluate_row(row, split, limit, out_dir, args.stride)
        print(
            f"{row.label:>24} [{row.geometry}]: object PSNR {res['object_psnr_raw']:.2f} raw / "
            f"{res['object_psnr_aligned']:.2f} aligned (input {res['input_object_psnr_raw']:.2f} / "
            f"{res['input_object_psnr_aligned']:.2f}), ST-LPIPS {res['object_stlpips']:.4f} "
            f"(input {res['input_object_stlpips']:.4f}), closer {100 * res['closer_than_input']:.0f}%",
            flush=True,
        )
        results.append(res)
    payload = {"machine": meta, "split": str(split), "rows": results}
    name = f"{NAME}_{split.name}" if not args.quick else f"{NAME}_quick"
    payload["pair_stride"] = args.stride
    for path in common.write_results(
        name, payload, figure(results, split.name), args.update_baseline
    ):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
