"""Re-shading, not recolouring (issue 31): relighting quality vs training time and parameters, by where
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
        EvaluationConfig,
        dataset_pairs,
        evaluate_dataset,
    )
    from gaffer_diffusion.geometry.estimator import shipped_normal_estimator_path
    from gaffer_diffusion.loading import load_pretrained
    from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
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
    config = EvaluationConfig(
        sampling=SamplingConfig(
            num_inference_steps=suggested.num_inference_steps,
            guidance_scale=float(suggested.guidance_scale),
            average_samples=suggested.average_samples,
            mirror_average=suggested.mirror_average,
        ),
        seed=0,
        batch_size=8,
        compat=suggested.compat,
        keep_background=True,
        object_fraction=None
        if suggested.object_fraction is None
        else float(suggested.object_fraction),
    )
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
    # each pair's target map (file stem), so tables by target HDRI come from this file alone
    document["pair_target_envmap"] = {
        p.name: Path(p.lighting.source).stem if isinstance(p.lighting, EnvmapLighting) else None
        for p in pairs
    }
    (out_dir / f"{split.name}-{row.label}.json").write_text(json.dumps(document, indent=2) + "\n")
    r, b = result.report, result.baseline
    assert r.mean_object_raw is not None and r.mean_object_aligned is not None
    assert b is not None and b.mean_object_raw is not None and b.mean_object_aligned is not None
    return {
        "label": row.label,
        "hint_geometry": row.geometry,
        "train_seconds": row.train_seconds,
        "parameters": params,
        "pairs": len(pairs),
        "object_psnr_raw": r.mean_object_raw.psnr,
        "object_psnr_aligned": r.mean_object_aligned.psnr,
        "object_stlpips": r.mean_object_raw.perceptual,
        "closer_than_input": result.closer_than_input,
        "full_psnr": r.mean_raw.psnr,
        "input_object_psnr_raw": b.mean_object_raw.psnr,
        "input_object_psnr_aligned": b.mean_object_aligned.psnr,
        "input_object_stlpips": b.mean_object_raw.perceptual,
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
    args = parser.parse_args(argv)
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
