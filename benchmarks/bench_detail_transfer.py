"""Detail transfer vs bicubic upsampling: gaffer-tiny's 128 px result brought back to 512 px renders.

`relight` returns the photo at its own size. Held-out objects (six gaffer-data procedural
recipe objects of seed 7, and pymeshlab's cow, which gaffer-tiny's model card keeps for its test split)
are rendered by gaffer-data at 512 px under its test-split HDRIs `courtyard` and `sunset` (3 draws per
view: yaw and mirroring vary). Each (input lighting 0 -> target lighting k) pair runs through what `relight` does: the
512 px input render framed and shrunk for the 128 px model (`gaffer_diffusion.photo.prepare_photo`),
gaffer-tiny relights it with its model card's settings, and the result goes back to 512 px by

- `resize`: the model's output upsampled bicubically (`paste_back(detail="resize")`), or
- `transfer`: the model's change of shading applied to the 512 px input (`paste_back(detail="transfer")`:
  linear-light ratio, push-pull fill, guided filter steered by the input);

both scored against the 512 px ground-truth render: PSNR over the object mask (alpha-weighted) and
shift-tolerant LPIPS on the object's crop, both on white; beside `input` (the unrelit 512 px input)
for scale. Cost: milliseconds of the paste-back step alone (the model's sampling is the same for both).

The renders are made once (needs gaffer-data[render], Blender's bpy) and cached under
`results/runs/detail_transfer_renders/` (git-ignored); `GAFFER_BENCH_DT_RENDERS=DIR` points at others.
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
import torch

NAME = "detail_transfer"
RESOLUTION = 512
SAMPLES = 16
VARIANTS = ("input", "resize", "transfer")
HELD_OUT_HDRIS = ("courtyard", "sunset")
"""Two of the HDRIs of gaffer-tiny's test split (its model card), in the gaffer-data recipe."""


def renders(quick: bool) -> Path:
    """A gaffer-data render of held-out procedural objects at 512 px (made once, then reused)."""
    env = os.environ.get("GAFFER_BENCH_DT_RENDERS")
    if env:
        return Path(env)
    root = common.RUNS / "detail_transfer_renders"
    out = root / "renders"
    if (out / "dataset.json").is_file() and list(out.glob("objects/*/manifest.json")):
        return out
    root.mkdir(parents=True, exist_ok=True)
    exe = Path(sys.executable).parent
    common.log(f"  rendering {RESOLUTION} px held-out objects into {out} (once)")
    subprocess.run(
        [str(exe / "gaffer-data"), "recipe", "--procedural", "6", "--seed", "7", str(root / "r")],
        check=True,
    )
    # only what gaffer-tiny never trained on: new procedural objects, the cow, its test HDRIs
    held = {"objects": root / "held" / "objects", "envmaps": root / "held" / "envmaps"}
    for folder in held.values():
        folder.mkdir(parents=True, exist_ok=True)
    for mesh in [
        *(root / "r" / "objects" / "procedural").iterdir(),
        root / "r/objects/cow/cow.obj",
    ]:
        shutil.copy2(mesh, held["objects"] / mesh.name)
    for name in HELD_OUT_HDRIS:
        shutil.copy2(root / "r" / "envmaps" / f"{name}.exr", held["envmaps"] / f"{name}.exr")
    subprocess.run(
        [
            str(exe / "gaffer-data"),
            "render",
            "--objects",
            str(held["objects"]),
            "--envmaps",
            str(held["envmaps"]),
            "--out",
            str(out),
            "--lightings",
            "3",
            "--views",
            "1",
            "--resolution",
            str(RESOLUTION),
            "--samples",
            str(SAMPLES),
            "--workers",
            "1",
            "--no-area-light",
            "--no-progress",
        ],
        check=True,
    )
    return out


def on_white(rgba: np.ndarray) -> torch.Tensor:
    """`[3, H, W]` float of an 8-bit straight-alpha RGBA image over white."""
    a = rgba[..., 3:4].astype(np.float32) / 255.0
    rgb = rgba[..., :3].astype(np.float32) / 255.0
    return torch.from_numpy(rgb * a + (1.0 - a)).permute(2, 0, 1)


def evaluate(pairs: Any, quick: bool) -> dict[str, Any]:
    from PIL import Image

    from gaffer_diffusion import pretrained
    from gaffer_diffusion.conditioning import RelightingConditions
    from gaffer_diffusion.demo import load_model
    from gaffer_diffusion.evaluation import pair_lighting
    from gaffer_diffusion.metrics import load_perceptual, masked_psnr, object_crop_box
    from gaffer_diffusion.photo import paste_back, prepare_photo, read_photo
    from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig
    from gaffer_diffusion.suggested import read_default_sampling

    model = load_model(None).model
    size = model.config.resolution
    pipe = RelightPipeline(model, RuntimeConfig(device="cpu"))
    # the model's own setting, from its manifest (what `relight` runs when no flag overrides it)
    suggested = read_default_sampling(pretrained.gaffer_tiny_path())
    sampling = suggested.sampling_config()
    perceptual = load_perceptual()
    reps = 3 if quick else 7
    rows: list[dict[str, Any]] = []
    ms: dict[str, list[float]] = {"resize": [], "transfer": []}
    for k, pair in enumerate(pairs):
        photo = read_photo(pair.input_image)
        if photo.alpha is None:
            raise RuntimeError(f"{pair.input_image} has no alpha (render with transparent film)")
        prepared = prepare_photo(photo, photo.alpha, size=size, compat="default")
        lighting = pair_lighting([pair], size, suggested.compat)
        cond = RelightingConditions(
            image=prepared.model_input.image,
            mask=prepared.model_input.mask,
            lighting=lighting,
        )
        relit = pipe(cond, sampling, seeds=[k]).images[0].cpu()
        gt_rgba = np.asarray(Image.open(pair.target_image).convert("RGBA"))
        gt = on_white(gt_rgba)[None]
        mask = torch.from_numpy(gt_rgba[..., 3].astype(np.float32) / 255.0)[None, None]
        top, left, bottom, right = object_crop_box(mask[0])
        row: dict[str, Any] = {"pair": pair.name}
        outs = {"input": np.dstack([photo.rgb_u8, photo.alpha_u8])}
        for detail in ("resize", "transfer"):
            outs[detail] = paste_back(prepared, relit, detail=detail)
            times = [
                common.time_calls(
                    lambda p=prepared, r=relit, d=detail: paste_back(p, r, detail=d), 1
                )
                for _ in range(reps)
            ]
            ms[detail].append(1e3 * float(np.median(times)))
        for name in VARIANTS:
            pred = on_white(outs[name])[None]
            row[f"{name}_psnr_object"] = round(float(masked_psnr(pred, gt, mask)[0]), 3)
            crop = (slice(None), slice(None), slice(top, bottom), slice(left, right))
            row[f"{name}_stlpips_crop"] = round(float(perceptual(pred[crop], gt[crop])[0]), 4)
        rows.append(row)
        common.log(
            f"  {pair.name}: PSNR input {row['input_psnr_object']:.2f} / resize "
            f"{row['resize_psnr_object']:.2f} / transfer {row['transfer_psnr_object']:.2f} dB"
        )
        if k == 0:
            strip = np.concatenate(
                [
                    (on_white(outs[n]).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
                    for n in VARIANTS
                ]
                + [(gt[0].permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)],
                axis=1,
            )
            common.RUNS.mkdir(parents=True, exist_ok=True)
            Image.fromarray(strip).save(common.RUNS / f"{NAME}_example.png")
    summary = {
        name: {
            "psnr_object_db": round(float(np.mean([r[f"{name}_psnr_object"] for r in rows])), 3),
            "stlpips_crop": round(float(np.mean([r[f"{name}_stlpips_crop"] for r in rows])), 4),
            **(
                {"paste_ms": common.Spread.of(ms[name]).to_dict()}
                if name in ms
                else {"paste_ms": None}
            ),
        }
        for name in VARIANTS
    }
    # which weights: `load_model(None)` is the shipped gaffer-tiny
    return {
        "model": common.model_provenance(),
        "model_resolution": size,
        "sampling": suggested.to_json(),
        "pairs": rows,
        "summary": summary,
    }


def figure(result: dict[str, Any], meta: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result["summary"]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.4))
    names = list(VARIANTS)
    colours = ["#999999", "#1f77b4", "#d62728"]
    axes[0].bar(names, [s[n]["psnr_object_db"] for n in names], color=colours)
    axes[0].set_title("PSNR over the object (dB, higher is better)")
    axes[0].set_ylim(min(s[n]["psnr_object_db"] for n in names) - 2, None)
    axes[1].bar(names, [s[n]["stlpips_crop"] for n in names], color=colours)
    axes[1].set_title("ST-LPIPS, object crop (lower is better)")
    axes[2].bar(
        ["resize", "transfer"],
        [s[n]["paste_ms"]["median"] for n in ("resize", "transfer")],
        color=colours[1:],
    )
    axes[2].set_title("paste-back cost (ms per 512 px image)")
    fig.suptitle(
        f"{result['model']['name']} {result['model']['version']} ({result['model_resolution']} px) "
        f"to {RESOLUTION} px: "
        f"{len(result['pairs'])} held-out pairs; {common.short_device(meta)}",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def markdown(result: dict[str, Any]) -> str:
    s = result["summary"]
    lines = [
        "| 512 px result | PSNR object (dB) | ST-LPIPS crop | paste-back ms (median) |",
        "|---|---|---|---|",
    ]
    for n in VARIANTS:
        cost = "-" if s[n]["paste_ms"] is None else f"{s[n]['paste_ms']['median']:.1f}"
        lines.append(
            f"| {n} | {s[n]['psnr_object_db']:.2f} | {s[n]['stlpips_crop']:.4f} | {cost} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    common.log(f"{NAME}: {meta['device']}, torch threads {threads}, quick={args.quick}")
    from gaffer_diffusion.evaluation import dataset_pairs

    root = renders(args.quick)
    pairs = dataset_pairs(root, input_lighting=0, limit=2 if args.quick else None)
    result = evaluate(pairs, args.quick)
    payload = {
        "benchmark": NAME,
        "quick": args.quick,
        "config": {
            "renders": "gaffer-data recipe --procedural 6 --seed 7: its 6 procedural objects and the "
            f"cow under {', '.join(HELD_OUT_HDRIS)} (gaffer-tiny's test split); render --resolution "
            f"{RESOLUTION} --samples {SAMPLES} --lightings 3 --views 1 --no-area-light",
            "input_lighting": 0,
            "sampling": "gaffer-tiny's suggested sampling, from its manifest (see 'sampling')",
            "metrics": "PSNR over the alpha mask and ST-LPIPS on the object's crop, images on white",
            "timing": "paste_back alone, median of repeated calls per pair, then the spread over pairs",
        },
        "machine": meta,
        "data": common.data_provenance(root),
        **result,
    }
    written = common.write_results(NAME, payload, figure(result, meta), args.update_baseline)
    print(markdown(result))
    base = common.load_baseline(NAME)
    if base is not None and not args.update_baseline:
        print("\nbaseline:\n" + markdown(base))
    common.log("wrote " + ", ".join(str(p) for p in written))
    return 0


if __name__ == "__main__":
    sys.exit(main())
