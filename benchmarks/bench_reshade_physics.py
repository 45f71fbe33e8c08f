"""Re-shading with no learning, scored as bench_reshade scores gaffer-tiny: how far physics alone goes.

Three plain reference twins of the learned relighter, each run through `evaluate_dataset` with the
model card's crop, mask, 8-bit quantisation and scores (object PSNR raw and channel-aligned, ST-LPIPS,
share of pairs closer than the unrelit input), on the same pairs as the card's validation rows:

- `ratio-estimated`: the de-lit ratio applied to the input in linear light, input x E_target(n) / pi
  / L_input(n), with gaffer-normals' estimate (`gaffer_diffusion.hints.diffuse_radiance` and
  `input_radiance_fit`, the very functions behind the model's de-lit-ratio hint), scaled to keep the
  input's mean level (one photo does not give the light level; the input's is the neutral guess).
  What the hints alone say, with the geometry every user path has.
- `ratio-true`: the same with Blender's true normals (an oracle: not a user path).
- `intrinsic-true`: Blender's albedo pass x E_target(n) / pi with true normals: the render's own
  diffuse colour under the target light with no visibility and no gloss (an oracle twice over).

Beside them the summary copies the model's rows on the same split from `reshade_<split>.json`
(gaffer-tiny 0.7 with estimated and with true normals), so one file holds the comparison. Validation
only: no choice is made here, and no test split is read.

Run: `flock /tmp/gaffer-cpu.lock python benchmarks/bench_reshade_physics.py --threads 2
[--split DIR] [--stride 2] [--update-baseline]`; `--quick` runs on `bench_reshade.py`'s tiny render
(2 objects, made once with bpy), to check the script, not to measure.
"""

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import _common as common
import gaffer_tiny_card as card
import numpy as np
import torch
import torch.nn.functional as F
from bench_reshade import quick_split, true_normals_reader

NAME = "reshade_physics"
DEFAULT_SPLIT = common.RESULTS.parent.parent / "packages/gaffer-diffusion/runs/data/render_val05"
ROWS = ("ratio-estimated", "ratio-true", "intrinsic-true")
# the model's rows on the same split and pairs, copied from bench_reshade's summary when present
MODEL_ROWS = ("stage6-800", "stage6-800-true-normals")
_CPU_RUNTIME = SimpleNamespace(device="cpu", dtype="float32")


@dataclass(frozen=True)
class PhysicsRelighter:
    """Duck-types `RelightPipeline` for `evaluate_dataset`: relights each batch by formula.

    `albedo_of` is filled per pair (in batch order) by the normals callback when the row needs the
    albedo pass; `evaluate_dataset` builds a batch's conditions just before relighting it.
    """

    kind: str
    model: Any
    albedo_queue: list[torch.Tensor]

    @property
    def runtime(self) -> Any:
        """What `evaluate_dataset` records as the device and dtype."""
        return _CPU_RUNTIME

    def __call__(self, cond: Any, sampling: Any, seeds: Any = None) -> Any:
        from gaffer_diffusion.geometry import input_normals
        from gaffer_diffusion.hints import diffuse_radiance, input_radiance_fit
        from gaffer_diffusion.images import linear_to_srgb, srgb_to_linear
        from gaffer_diffusion.pipelines.relight import RelightOutput

        image, mask = cond.image.float(), cond.mask.float()
        normals = (
            cond.normals.float()
            if cond.normals is not None
            else input_normals("estimated", image, mask)
        )
        shading = diffuse_radiance(normals, cond.lighting.ldr, cond.lighting.hdr)
        linear = srgb_to_linear(image)
        if self.kind == "intrinsic-true":
            albedo = torch.stack([self.albedo_queue.pop(0) for _ in range(image.shape[0])])
            relit = albedo * shading
        else:
            fit = input_radiance_fit(image, mask, normals)
            relit = linear * (shading + 0.01) / (fit + 0.01)
            inside = (mask > 0.5).float()
            level_in = (linear * inside).sum(dim=(1, 2, 3)) / inside.sum(dim=(1, 2, 3)).clamp_min(1)
            level_out = (relit * inside).sum(dim=(1, 2, 3)) / inside.sum(dim=(1, 2, 3)).clamp_min(1)
            relit = relit * (level_in / level_out.clamp_min(1e-6)).view(-1, 1, 1, 1)
        display = linear_to_srgb(relit.clamp(0.0, 1.0))
        out = image + mask * (display - image)
        return RelightOutput(images=out, latents=torch.zeros(out.shape[0], 4, 1, 1))


def _albedo_reader(split: Path, queue: list[torch.Tensor]) -> Any:
    from gaffer_data import read_object
    from gaffer_diffusion.images import crop_square
    from gaffer_envmap.io_exr import read_exr_array

    objects: dict[str, Any] = {}

    def push(pair: Any, box: Any, size: int) -> None:
        if pair.object_id not in objects:
            objects[pair.object_id] = read_object(split / "objects" / pair.object_id)
        obj = objects[pair.object_id]
        view = next(v for v in obj.views if v.index == pair.view_index)
        albedo = read_exr_array(obj.path(view.area.albedo))[..., :3].astype(np.float32)
        if box is not None:
            albedo = crop_square(albedo, box, 0.0)
        t = torch.from_numpy(np.ascontiguousarray(albedo)).permute(2, 0, 1)[None]
        queue.append(F.interpolate(t, size=(size, size), mode="bilinear", antialias=True)[0])

    return push


def score_row(kind: str, split: Path, stride: int, limit: int | None) -> dict[str, Any]:
    from gaffer_diffusion.evaluation import (
        dataset_pairs,
        evaluate_dataset,
        suggested_evaluation_config,
    )
    from gaffer_diffusion.pretrained import gaffer_tiny_path, load_gaffer_tiny
    from gaffer_diffusion.suggested import read_suggested_sampling

    # the shipped model only sets the working resolution and the card's sampling settings
    model = load_gaffer_tiny().model
    config = suggested_evaluation_config(
        read_suggested_sampling(gaffer_tiny_path()), seed=0, batch_size=8
    )
    pairs = dataset_pairs(split, limit=limit)[::stride]
    queue: list[torch.Tensor] = []
    relighter = PhysicsRelighter(kind=kind, model=model, albedo_queue=queue)
    normals_of = None
    if kind != "ratio-estimated":
        true_normals = true_normals_reader(split)
        push_albedo = _albedo_reader(split, queue) if kind == "intrinsic-true" else None

        def normals_of(pair: Any, box: Any, size: int) -> torch.Tensor:
            if push_albedo is not None:
                push_albedo(pair, box, size)
            return true_normals(pair, box, size)

    start = time.perf_counter()
    result = evaluate_dataset(
        relighter,  # type: ignore[arg-type]
        pairs,
        config,
        settings={"label": kind, "pair_stride": stride},
        normals_of=normals_of,
    )
    return {
        "label": kind,
        "hint_geometry": "estimated" if kind == "ratio-estimated" else "true",
        "learned": False,
        **card.row_means(json.loads(result.to_json())),
        "eval_seconds": round(time.perf_counter() - start, 1),
    }


def _model_rows(split_name: str, stride: int) -> list[dict[str, Any]]:
    path = common.RESULTS / f"reshade_{split_name}.json"
    if not path.is_file():
        return []
    keep = ("label", "hint_geometry", "release", "unet_sha256", "pair_stride", "pairs")
    out = []
    for row in json.loads(path.read_text())["rows"]:
        if row["label"] in MODEL_ROWS and row.get("pair_stride", stride) == stride:
            means = {k: v for k, v in row.items() if k.startswith(("object_", "input_", "closer"))}
            out.append({**{k: row.get(k) for k in keep}, "learned": True, **means})
    return out


def figure(rows: list[dict[str, Any]], title: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.6))
    labels = [r["label"] for r in rows]
    x = np.arange(len(rows))
    raw = [r["object_psnr_raw"] - r["input_object_psnr_raw"] for r in rows]
    aligned = [r["object_psnr_aligned"] - r["input_object_psnr_aligned"] for r in rows]
    ax.bar(x - 0.2, raw, 0.4, label="object PSNR raw - input's")
    ax.bar(x + 0.2, aligned, 0.4, label="object PSNR aligned - input's")
    ax.axhline(4.5, color="C0", ls=":", lw=1, label="issue 31 targets (raw 4.5, aligned 3)")
    ax.axhline(3.0, color="C1", ls=":", lw=1)
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xticks(x, labels, rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("gain over the unrelit input (dB)")
    ax.set_title(title, fontsize=8)
    ax.legend(fontsize=7)
    return fig


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--split", type=Path, default=DEFAULT_SPLIT)
    parser.add_argument("--stride", type=int, default=2, help="score every N-th pair (card: 2)")
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--update-baseline", action="store_true")
    args = parser.parse_args(argv)
    if args.stride < 1:
        parser.error(f"--stride is {args.stride}; pass 1 (every pair) or more")
    threads = common.set_threads(args.threads)
    split, limit = (quick_split(), 4) if args.quick else (args.split, None)
    if not (split / "dataset.json").is_file():
        raise SystemExit(
            f"--split {split}: no dataset.json; render it as the gaffer-tiny card's Data section says"
        )
    meta = common.machine(threads)
    rows = []
    for kind in ROWS:
        row = score_row(kind, split, args.stride, limit)
        print(
            f"{kind:>16}: object PSNR {row['object_psnr_raw']:.2f} raw / "
            f"{row['object_psnr_aligned']:.2f} aligned (input {row['input_object_psnr_raw']:.2f} / "
            f"{row['input_object_psnr_aligned']:.2f}), closer {100 * row['closer_than_input']:.0f}%",
            flush=True,
        )
        rows.append(row)
    model_rows = [] if args.quick else _model_rows(split.name, args.stride)
    payload = {
        **common.model_result_header(NAME, __doc__, split, pair_stride=args.stride),
        "machine": meta,
        "rows": rows,
        "model_rows_from": f"benchmarks/results/reshade_{split.name}.json" if model_rows else None,
        "model_rows": model_rows,
    }
    name = NAME if not args.quick else f"{NAME}_quick"
    title = f"no-learning re-shading vs gaffer-tiny on {split.name}\n{common.short_device(meta)}"
    for path in common.write_results(
        f"{name}_{split.name}" if not args.quick else name,
        payload,
        figure(rows + model_rows, title),
        args.update_baseline,
    ):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
