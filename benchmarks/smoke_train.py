"""CPU smoke training: render a tiny dataset, train a small config, report the numbers honestly.

    python benchmarks/smoke_train.py --out DIR [--minutes 3] [--threads 1]

Research scaffolding, not part of the gaffer-diffusion wheel (it reads the repository's
`packages/gaffer-diffusion/configs/tiny-smoke.json` and drives the `gaffer-data` CLI): `nox -s
smoke_train` runs it and checks its report. Not a benchmark (`nox -s bench` runs only `bench_*.py`).

Stages (each reused when its output already exists in DIR):

1. `DIR/data/recipe`, `DIR/data/render`: gaffer-data's embedded recipe (bundled CC0 HDRIs, pymeshlab's
   sample meshes, procedural Blender objects) rendered at 64 px with few samples, through the
   `gaffer-data` command line in subprocesses (bpy stays out of this process).
2. `DIR/init`: the config's preset, random-initialised. The default (`configs/tiny-smoke.json`) is the
   `gaffer-tiny` architecture, which works in pixel space: nothing to pretrain. A latent preset
   (`tiny`) first has its random VAE fitted as a plain autoencoder for `--vae-seconds` (a random decoder
   cannot draw images, so the diffusion loss would fall while every relit image stays noise); the paper
   starts from pretrained Zero-1-to-3 XL instead.
3. `DIR/train`: the config trained for `--minutes` of wall time.
4. `DIR/smoke_report.json`: the loss at the start and the end of training, and on held-out objects the
   PSNR of the relit images, of the unrelit input (the identity baseline) and of the VAE reconstruction
   of the ground truth (the ceiling the VAE allows; exact in pixel space), against ground-truth renders.
"""

import argparse
import dataclasses
import json
import logging
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gaffer_diffusion.configs import get_preset
from gaffer_diffusion.loading import save_pretrained
from gaffer_diffusion.metrics import psnr
from gaffer_diffusion.models.build import build_model
from gaffer_diffusion.models.model import NeuralGafferModel, vae_decode, vae_posterior
from gaffer_diffusion.training.config import ValidationConfig, load_config
from gaffer_diffusion.training.dataset import RelightTrainDataset, split_object_ids
from gaffer_diffusion.training.loop import load_checkpoint_model, train
from gaffer_diffusion.training.tracking import read_log
from gaffer_diffusion.training.validation import build_validation_set, validate

logger = logging.getLogger("smoke_train")

CONFIG = (
    Path(__file__).resolve().parents[1]
    / "packages"
    / "gaffer-diffusion"
    / "configs"
    / "tiny-smoke.json"
)


def render_dataset(out: Path, *, procedural: int, views: int, lightings: int, samples: int) -> Path:
    """Render (or reuse) the smoke dataset with the `gaffer-data` CLI; returns the render folder."""
    recipe, render = out / "recipe", out / "render"
    if (render / "dataset.json").is_file() and any((render / "objects").glob("*/manifest.json")):
        logger.info("reusing the rendered dataset in %s", render)
        return render
    py = [sys.executable, "-m", "gaffer_data.cli"]
    t0 = time.perf_counter()
    subprocess.run(
        [*py, "recipe", str(recipe), "--procedural", str(procedural)],
        check=True,
        capture_output=True,
    )
    cmd = [
        *py,
        "render",
        "--objects",
        str(recipe / "objects"),
        "--envmaps",
        str(recipe / "envmaps"),
        "--out",
        str(render),
        "--views",
        str(views),
        "--lightings",
        str(lightings),
        "--resolution",
        "64",
        "--samples",
        str(samples),
        "--no-denoise",
        "--world-map-resolution",
        "64",
        "--no-progress",
    ]
    result = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if not (render / "dataset.json").is_file():
        raise RuntimeError(f"`gaffer-data render` failed:\n{result.stderr[-3000:]}")
    logger.info(
        "rendered the dataset in %.0f s: %s", time.perf_counter() - t0, result.stdout.strip()
    )
    return render


def fit_autoencoder(
    model: NeuralGafferModel, images: torch.Tensor, seconds: float, *, seed: int = 0
) -> dict[str, float]:
    """Fit the random tiny VAE as an autoencoder (MSE + 1e-6 KL) on `[N, 3, H, W]` images in [0, 1]."""
    vae = model.vae.train()
    opt = torch.optim.Adam(vae.parameters(), lr=2e-3)
    g = torch.Generator().manual_seed(seed)
    t0, steps, loss = time.perf_counter(), 0, torch.tensor(0.0)
    while time.perf_counter() - t0 < seconds:
        idx = torch.randint(0, images.shape[0], (16,), generator=g)
        x = images[idx] * 2 - 1
        post = vae_posterior(vae, x)
        rec = vae_decode(vae, post.sample(generator=g))
        loss = torch.nn.functional.mse_loss(rec, x) + 1e-6 * post.kl().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        steps += 1
    vae.eval().requires_grad_(False)
    return {"vae_steps": steps, "vae_final_loss": float(loss)}


@torch.no_grad()
def vae_ceiling(model: NeuralGafferModel, images: torch.Tensor) -> float | None:
    """Mean PSNR of `decode(mode(encode(x)))` against x: the best the VAE can draw (None: exact, as in
    pixel space, where the PSNR is infinite)."""
    z = vae_posterior(model.vae, images * 2 - 1).mode()
    rec = (vae_decode(model.vae, z) / 2 + 0.5).clamp(0, 1)
    value = float(psnr(torch.round(rec * 255) / 255, images).mean())
    return value if np.isfinite(value) else None


def run(args: argparse.Namespace) -> dict[str, Any]:
    """All stages; returns the report (also written to `OUT/smoke_report.json`)."""
    out: Path = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(args.threads)
    t_all = time.perf_counter()
    render = render_dataset(
        out / "data",
        procedural=args.procedural,
        views=args.views,
        lightings=args.lightings,
        samples=args.samples,
    )
    base = load_config(args.config)
    cfg = dataclasses.replace(
        base,
        output_dir=out / "train",
        data=dataclasses.replace(base.data, root=render),
        train=dataclasses.replace(base.train, max_time_s=args.minutes * 60.0),
    )
    from gaffer_data import open_dataset

    train_ids, val_ids = split_object_ids(open_dataset(render).object_ids, cfg.data.val_objects)
    preset = get_preset(cfg.model.preset)
    res = preset.resolution
    train_ds = RelightTrainDataset([render], cfg.data, res, seed=0, include=train_ids)

    init = out / "init"
    vae_stats: dict[str, float] = {}
    if not (init / "gaffer_model.json").is_file():
        model = build_model(preset, seed=cfg.model.seed)
        if preset.vae.kind != "pixel":
            imgs = torch.stack(
                [t for k in range(min(len(train_ds) * 4, 256)) for t in train_ds[k].target_images]
            )
            vae_stats = fit_autoencoder(model, imgs, args.vae_seconds)
        save_pretrained(model, init)
    cfg = dataclasses.replace(
        cfg, model=dataclasses.replace(cfg.model, init="pretrained", path=init)
    )
    ckpt_dir = cfg.output_dir / "checkpoints"
    resume = ckpt_dir.is_dir() and any(ckpt_dir.glob("checkpoint-*"))
    result = train(cfg, resume=resume)
    seconds = result.seconds
    if result.step < args.min_steps and result.checkpoint is not None:
        # a slow CPU (e.g. no native bf16: fp32, several times slower) gets too few steps in the time
        # limit for "the loss falls" to mean anything: go on, resume-exact, to `--min-steps`
        logger.info(
            "%d steps in the %.1f-minute limit; continuing to --min-steps %d",
            result.step,
            args.minutes,
            args.min_steps,
        )
        longer = dataclasses.replace(
            cfg, train=dataclasses.replace(cfg.train, max_time_s=None, max_steps=args.min_steps)
        )
        result = train(longer, resume=True)
        seconds += result.seconds

    rows = read_log(cfg.output_dir / "logs" / "train.jsonl")
    losses = [r["loss"] for r in rows if r.get("loss") is not None]
    # first / last 10% of the logged rows, at least 3 each when there are 6 or more (one row is noise)
    k = max(1, min(len(losses) // 2, max(3, len(losses) // 10)))
    vcfg = ValidationConfig(
        num_samples=args.val_samples,
        num_inference_steps=args.val_steps,
        guidance_scale=1.0,
        batch_size=8,
        seed=1234,
    )
    val_ds = RelightTrainDataset(
        [render],
        dataclasses.replace(cfg.data, targets_per_sample=1),
        res,
        seed=vcfg.seed,
        include=val_ids,
    )
    valset = build_validation_set(val_ds, vcfg.num_samples)
    if result.checkpoint is None:
        raise RuntimeError(f"smoke training wrote no checkpoint under {ckpt_dir}")
    model = load_checkpoint_model(result.checkpoint, use_ema=True)
    scores = {}
    # one step from t=999 is the model's estimate of E[target | conditions] (the PSNR-optimal
    # prediction); more steps trade PSNR for sharper, noisier samples
    for steps, scale in (
        (1, 1.0),
        (vcfg.num_inference_steps, 1.0),
        (vcfg.num_inference_steps, 3.0),
    ):
        v = validate(
            model,
            valset,
            dataclasses.replace(vcfg, guidance_scale=scale, num_inference_steps=steps),
            step=result.step,
            compat=cfg.data.lighting_compat,
            device=torch.device("cpu"),
            sheet_dir=out / f"val-steps{steps}-guidance{scale:g}",
        )
        scores[f"steps_{steps}_guidance_{scale:g}"] = {
            "psnr_relit": v.psnr,
            "psnr_per_item": v.psnr_per_item,
            "sheet": str(v.sheet),
        }
    identity = float(psnr(valset.input_images, valset.target_images).mean())
    report = {
        "dataset": {
            "render": str(render),
            "train_objects": len(train_ids),
            "val_objects": list(val_ids),
            "train_views": len(train_ds),
            "val_pairs": valset.size,
            "resolution": res,
        },
        "model": {
            "preset": preset.name,
            "space": "pixel" if preset.vae.kind == "pixel" else "latent",
            "prediction_type": preset.scheduler.prediction_type,
        },
        "vae_pretraining": vae_stats,
        "training": {
            "steps": result.step,
            "stop_reason": result.stop_reason,
            "seconds": seconds,
            "batch_size": cfg.train.batch_size,
            "targets_per_sample": cfg.data.targets_per_sample,
            "loss_first_10pct": float(np.mean(losses[:k])) if losses else None,
            "loss_last_10pct": float(np.mean(losses[-k:])) if losses else None,
            "loss_falls": bool(losses) and float(np.mean(losses[-k:])) < float(np.mean(losses[:k])),
            "skipped_steps": result.skipped_steps,
            "skipped_samples": result.skipped_samples,
            "end_training_errors": result.end_training_errors,
        },
        "heldout_psnr_db": {
            "identity_baseline": identity,
            "vae_reconstruction_ceiling": vae_ceiling(model, valset.target_images),
            **scores,
            "sampler": f"DDIM ({preset.scheduler.timestep_spacing} timesteps), EMA weights",
        },
        "beats_identity": any(s["psnr_relit"] > identity for s in scores.values()),
        "total_seconds": time.perf_counter() - t_all,
    }
    (out / "smoke_report.json").write_text(json.dumps(report, indent=2))
    return report


def main(argv: list[str] | None = None) -> int:
    """Entry point; writes `OUT/smoke_report.json` and returns 0."""
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--config", type=Path, default=CONFIG)
    p.add_argument("--minutes", type=float, default=3.0, help="diffusion training wall time")
    p.add_argument(
        "--min-steps",
        type=int,
        default=150,
        help="train on past --minutes until this many steps (slow CPUs; 0: the time limit only)",
    )
    p.add_argument("--vae-seconds", type=float, default=60.0, help="autoencoder fitting time")
    p.add_argument(
        "--threads", type=int, default=1, help="torch threads (1 is fastest on 2 busy cores)"
    )
    p.add_argument("--procedural", type=int, default=6)
    p.add_argument("--views", type=int, default=4)
    p.add_argument("--lightings", type=int, default=6)
    p.add_argument("--samples", type=int, default=16)
    p.add_argument("--val-samples", type=int, default=16)
    p.add_argument("--val-steps", type=int, default=25)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    report = run(args)
    logger.info("report: %s", json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
