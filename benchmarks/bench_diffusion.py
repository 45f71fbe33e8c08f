"""Diffusion speed (full-size model) and sampler accuracy (steps x scheduler) of gaffer-diffusion.

Two parts, each writing JSON + PNG (see `_common.write_results`):

1. `diffusion_speed`: latency and throughput of the FULL-SIZE `neural-gaffer-256` model (859.5M-parameter
   UNet, SD VAE, CLIP ViT-L/14; random weights: speed does not depend on the values).
   - CPU (always): UNet forward at batch 1 and 2 (batch 2 = one CFG step of one image), conditioning
     encode (one batched VAE call for image/HDR/LDR + CLIP), VAE decode, an end-to-end 2-step DDIM
     sample with CFG 3, and the 50-step estimate encode + 50 x UNet(batch 2) + decode.
   - CUDA (only when a GPU is present): ours (bf16 weights, SDPA attention, with and without
     `torch.compile`, batch 1 / 4 / 16 / 64) against a re-creation of the authors' inference settings
     in the same process (fp32 weights under fp16 autocast, 50 DDIM steps, CFG 3, batch 4, posterior
     samples for the conditioning latents; attention through PyTorch SDPA, which stands in for their
     xformers kernel, so the comparison does not credit us for the attention kernel). Throughput is
     images per second at 50 DDIM steps with CFG 3 for both; targets: >= 5x theirs, and
     < 50 ms per image at a large batch.
2. `diffusion_steps`: DDIM / DPM-Solver++ / UniPC at 5 ... 50 steps, seconds per image vs accuracy
   against the 50-step DDIM output of the same seed and conditions (PSNR, and the perceptual distance:
   ST-LPIPS unless a standard LPIPS backbone is given), with the TINY model on CPU. The tiny model is
   random-init, so this measures how fast each sampler converges to the 50-step DDIM solution of the
   same network, not relighting quality.
3. `diffusion_quality`: the same samplers and steps with the TRAINED, shipped `gaffer-tiny` on its
   held-out example object (`gaffer_diffusion/data/example`: 4 views x 16 lightings of an object and
   HDRIs it never saw), scored against the ground-truth Cycles renders (PSNR raw and channel-aligned),
   beside the two baselines (the unrelit input; the input channel-aligned to the target): relighting
   quality against milliseconds per image.

Run: `python benchmarks/bench_diffusion.py [--quick] [--update-baseline] [--part speed|steps|quality|all]`.
`--quick` keeps the CPU run to about 3 minutes on 2 cores.
"""

import argparse
import gc
import sys
import time
from collections.abc import Callable
from typing import Any

import _common as common
import numpy as np
import torch

NAME_SPEED = "diffusion_speed"
NAME_STEPS = "diffusion_steps"
NAME_QUALITY = "diffusion_quality"
TARGET_SPEEDUP = 5.0  # ours >= 5x the authors' images/s at the same steps (H100/H200)
TARGET_MS_PER_IMAGE = 50.0  # < 50 ms per image at 50 steps with CFG, large batch


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="short run (about 3 minutes on 2 cores)")
    p.add_argument("--update-baseline", action="store_true", help="also write results/<name>.*")
    p.add_argument("--threads", type=int, default=0, help="torch intra-op threads (0 = all)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--part", choices=("all", "speed", "steps", "quality"), default="all")
    p.add_argument("--lpips-backbone", help="torchvision AlexNet weights: standard LPIPS in part 2")
    return p.parse_args(argv)


def _sync(device: str) -> Callable[[], None] | None:
    return torch.cuda.synchronize if device.startswith("cuda") else None


def _repeat(fn: Callable[[], object], reps: int, device: str, warmup: int = 1) -> list[float]:
    """Seconds per call, `reps` timed calls after `warmup` untimed ones."""
    sync = _sync(device)
    for _ in range(warmup):
        fn()
    return [common.time_calls(fn, 1, sync) for _ in range(reps)]


# ---------------------------------------------------------------------------------------------
# Part 1: speed of the full-size model
# ---------------------------------------------------------------------------------------------
def _unet_inputs(model: Any, batch: int, device: str, dtype: torch.dtype) -> dict[str, Any]:
    h = model.config.latent_size
    g = torch.Generator().manual_seed(0)
    x = torch.randn(batch, model.config.unet.in_channels, h, h, generator=g)
    ctx = torch.randn(batch, 1, model.config.unet.cross_attention_dim, generator=g)
    return {
        "sample": x.to(device, dtype),
        "timestep": torch.tensor(981, device=device),
        "encoder_hidden_states": ctx.to(device, dtype),
    }


def _conditions(batch: int, resolution: int, seed: int) -> Any:
    from gaffer_diffusion.testing import random_conditions

    return random_conditions(batch, resolution, seed=seed)


def speed_cpu(model: Any, quick: bool, seed: int) -> list[dict[str, Any]]:
    """Per-operation CPU latencies of the full-size model in float32 with SDPA attention."""
    from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig

    pipe = RelightPipeline(model, RuntimeConfig(device="cpu", dtype="float32", attention="sdpa"))
    reps = 1 if quick else 3
    res = model.config.resolution
    rows: list[dict[str, Any]] = []

    def record(op: str, batch: int, images: int, secs: list[float], **extra: Any) -> None:
        s = common.Spread.of(secs)
        rows.append(
            {
                "op": op,
                "batch": batch,
                "images": images,
                "seconds": s.to_dict(),
                # minimum over repetitions: other processes share the cores and only add time
                "ms_per_image": round(1000 * s.min / max(images, 1), 1),
                **extra,
            }
        )
        common.log(f"  cpu {op:<34} b{batch}: min {s.min:.3f} s, median {s.median:.3f} s (n={s.n})")

    # quick: one timed call per operation, with a single untimed warm-up call before the first one
    # (allocator, oneDNN kernels); the full run warms up every operation and repeats it 3 times.
    warm = 0 if quick else 1
    with torch.inference_mode():
        for k, b in enumerate((1, 2) if quick else (1, 2, 4)):
            kw = _unet_inputs(model, b, "cpu", torch.float32)
            secs = _repeat(
                lambda kw=kw: model.unet(**kw), reps, "cpu", warmup=1 if k == 0 else warm
            )
            record("unet_forward", b, b, secs, note="b2 = one CFG step of one image")
        cond = _conditions(1, res, seed)
        encoded: list[Any] = []
        secs = _repeat(lambda: encoded.append(pipe.encode(cond)), reps, "cpu", warmup=warm)
        record("encode (3x VAE enc + CLIP)", 1, 1, secs)
        enc = encoded[-1]
        z = torch.randn(1, 4, model.config.latent_size, model.config.latent_size)
        scale = model.config.vae.scaling_factor
        secs = _repeat(lambda: model.vae.decode(z / scale), reps, "cpu", warmup=warm)
        record("vae_decode", 1, 1, secs)
        sampling = SamplingConfig(num_inference_steps=2, guidance_scale=3.0)
        secs = _repeat(lambda: pipe.sample(enc, sampling, seeds=[seed]), reps, "cpu", warmup=0)
        record("sample 2 DDIM steps CFG3 + decode", 1, 1, secs)
    by = {(r["op"], r["batch"]): r["seconds"]["min"] for r in rows}
    est = (
        by[("encode (3x VAE enc + CLIP)", 1)] + 50 * by[("unet_forward", 2)] + by[("vae_decode", 1)]
    )
    rows.append(
        {
            "op": "estimate: 50 DDIM steps CFG3 (encode + 50 x unet b2 + decode)",
            "batch": 1,
            "images": 1,
            "seconds": {"min": round(est, 3)},
            "ms_per_image": round(1000 * est, 1),
        }
    )
    common.log(f"  cpu 50-step CFG estimate: {est:.1f} s per image")
    return rows


def _time_sampling(
    pipe: Any, batch: int, sampling: Any, reps: int, seed: int, autocast: torch.dtype | None
) -> list[float]:
    """Seconds per end-to-end call (encode + sample + decode) of `batch` images."""
    res = pipe.model.config.resolution
    cond = _conditions(batch, res, seed)

    def run() -> object:
        ctx = (
            torch.autocast("cuda", dtype=autocast)
            if autocast is not None
            else torch.autocast("cuda", enabled=False)
        )
        with ctx:
            return pipe(cond, sampling, seeds=list(range(batch)))

    return _repeat(run, reps, pipe.runtime.device, warmup=1)


def speed_cuda(quick: bool, seed: int) -> list[dict[str, Any]]:
    """Ours vs the authors' settings on the GPU (50 DDIM steps, CFG 3), images per second."""
    from gaffer_diffusion import (
        RelightPipeline,
        RuntimeConfig,
        SamplingConfig,
        build_model,
        get_preset,
    )

    sampling_ours = SamplingConfig(num_inference_steps=50, guidance_scale=3.0)
    # their inference draws posterior samples for the conditioning latents (official impl. section 1)
    sampling_theirs = SamplingConfig(
        num_inference_steps=50, guidance_scale=3.0, latent_mode="sample"
    )
    reps = 2 if quick else 4
    rows: list[dict[str, Any]] = []

    def record(variant: str, batch: int, secs: list[float], **extra: Any) -> dict[str, Any]:
        s = common.Spread.of(secs)
        row = {
            "variant": variant,
            "batch": batch,
            "steps": 50,
            "guidance_scale": 3.0,
            "seconds_per_call": s.to_dict(),
            "images_per_s": round(batch / s.median, 3),
            "ms_per_image": round(1000 * s.median / batch, 2),
            **extra,
        }
        rows.append(row)
        common.log(f"  cuda {variant:<34} b{batch}: {row['ms_per_image']:.1f} ms/img")
        return row

    # theirs: fp32 weights + fp16 autocast, batch 4
    model = build_model(get_preset("neural-gaffer-256"), seed=seed)
    pipe = RelightPipeline(model, RuntimeConfig(device="cuda", dtype="float32", attention="sdpa"))
    theirs = record(
        "theirs (fp32 + fp16 autocast, SDPA)",
        4,
        _time_sampling(pipe, 4, sampling_theirs, reps, seed, torch.float16),
        note="authors' settings; SDPA stands in for xformers",
    )
    del pipe, model
    gc.collect()
    torch.cuda.empty_cache()

    batches = (1, 4, 16) if quick else (1, 4, 16, 64)
    for compiled in (False, True):
        model = build_model(get_preset("neural-gaffer-256"), seed=seed)
        runtime = RuntimeConfig(device="cuda", dtype="bfloat16", attention="sdpa", compile=compiled)
        t0 = time.perf_counter()
        pipe = RelightPipeline(model, runtime)
        for b in batches:
            first = time.perf_counter()
            secs = _time_sampling(pipe, b, sampling_ours, reps, seed, None)
            row = record(f"ours (bf16, SDPA{', compile' if compiled else ''})", b, secs)
            row["first_call_s_incl_warmup"] = round(time.perf_counter() - first, 2)
            row["speedup_vs_theirs"] = round(row["images_per_s"] / theirs["images_per_s"], 2)
        rows[-1]["setup_s"] = round(time.perf_counter() - t0, 2)
        del pipe, model
        gc.collect()
        torch.cuda.empty_cache()
    return rows


def speed_figure(
    cpu_rows: list[dict[str, Any]], cuda_rows: list[dict[str, Any]], meta: dict
) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncols = 2 if cuda_rows else 1
    fig, axes = plt.subplots(1, ncols, figsize=(7 * ncols, 4.2), squeeze=False)
    ax = axes[0, 0]
    labels = [f"{r['op']} (b{r['batch']})" for r in cpu_rows]
    values = [r["seconds"]["min"] for r in cpu_rows]
    ax.barh(labels, values, color="tab:blue")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per call (min over repetitions), log scale")
    ax.set_title("neural-gaffer-256 on CPU, float32, SDPA", fontsize=10)
    for y, v in enumerate(values):
        ax.text(v, y, f" {v:.2f} s", va="center", fontsize=8)
    if cuda_rows:
        ax2 = axes[0, 1]
        labels = [f"{r['variant']} b{r['batch']}" for r in cuda_rows]
        ms = [r["ms_per_image"] for r in cuda_rows]
        colors = [
            "tab:red" if r["variant"].startswith("theirs") else "tab:green" for r in cuda_rows
        ]
        ax2.barh(labels, ms, color=colors)
        ax2.axvline(TARGET_MS_PER_IMAGE, color="k", ls="--", lw=1, label="target 50 ms")
        ax2.set_xlabel("ms per image, 50 DDIM steps, CFG 3")
        ax2.set_title(meta.get("gpu", "GPU"), fontsize=10)
        ax2.legend(fontsize=8)
    fig.suptitle(f"gaffer-diffusion speed; {common.short_device(meta)}", fontsize=9)
    fig.tight_layout()
    return fig


def run_speed(args: argparse.Namespace, meta: dict[str, Any]) -> list[str]:
    from gaffer_diffusion import build_model, get_preset

    common.log(f"{NAME_SPEED}: building neural-gaffer-256 with random weights")
    t0 = time.perf_counter()
    model = build_model(get_preset("neural-gaffer-256"), seed=args.seed)
    build_s = time.perf_counter() - t0
    params = {
        name: sum(p.numel() for p in getattr(model, name).parameters())
        for name in ("unet", "vae", "image_encoder")
    }
    common.log(f"  built in {build_s:.1f} s; parameters {params}")
    cpu_rows = speed_cpu(model, args.quick, args.seed)
    del model
    gc.collect()
    cuda_rows = speed_cuda(args.quick, args.seed) if torch.cuda.is_available() else []
    payload: dict[str, Any] = {
        "benchmark": NAME_SPEED,
        "quick": args.quick,
        "config": {
            "model": "neural-gaffer-256 (random weights)",
            "parameters": params,
            "resolution": 256,
            "latent": "4x32x32",
            "cpu_dtype": "float32",
            "attention": "sdpa",
            "cfg_scale": 3.0,
            "model_build_s": round(build_s, 1),
            "seed": args.seed,
        },
        "machine": meta,
        "cpu": cpu_rows,
        "cuda": cuda_rows or "unavailable: the ours-vs-theirs GPU comparison did not run",
    }
    if cuda_rows:
        ours = [r for r in cuda_rows if r["variant"].startswith("ours")]
        best = max(ours, key=lambda r: r["images_per_s"])
        payload["cuda_summary"] = {
            "best": best["variant"] + f" b{best['batch']}",
            "best_ms_per_image": best["ms_per_image"],
            "best_speedup_vs_theirs": best["speedup_vs_theirs"],
            "target_speedup": TARGET_SPEEDUP,
            "target_ms_per_image": TARGET_MS_PER_IMAGE,
            "meets_targets": best["speedup_vs_theirs"] >= TARGET_SPEEDUP
            and best["ms_per_image"] < TARGET_MS_PER_IMAGE,
        }
    fig = speed_figure(cpu_rows, cuda_rows, meta)
    return [str(p) for p in common.write_results(NAME_SPEED, payload, fig, args.update_baseline)]


# ---------------------------------------------------------------------------------------------
# Part 2: steps x scheduler vs time vs accuracy (tiny model, CPU)
# ---------------------------------------------------------------------------------------------
def run_steps(args: argparse.Namespace, meta: dict[str, Any]) -> list[str]:
    from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig
    from gaffer_diffusion.metrics import load_perceptual, psnr
    from gaffer_diffusion.testing import random_conditions, tiny_model

    schedulers = ("ddim", "dpmsolver++", "unipc")
    steps = (5, 10, 20, 50) if args.quick else (5, 10, 15, 20, 30, 50)
    batch = 4
    reps = 3 if args.quick else 5
    common.log(f"{NAME_STEPS}: tiny model, {schedulers} x {steps}, batch {batch}")
    # one thread: the tiny model gains nothing from more, and on shared cores a second OpenMP thread
    # that loses its core stalls every parallel region (timings then vary 10x)
    threads_before = torch.get_num_threads()
    torch.set_num_threads(1)
    model = tiny_model(seed=args.seed)
    pipe = RelightPipeline(model, RuntimeConfig(device="cpu", dtype="float32"))
    cond = random_conditions(batch, model.config.resolution, seed=args.seed)
    enc = pipe.encode(cond)
    seeds = list(range(args.seed, args.seed + batch))
    perceptual = load_perceptual(args.lpips_backbone)
    ref = pipe.sample(enc, SamplingConfig(num_inference_steps=50), seeds=seeds).images
    rows = []
    for sched in schedulers:
        for n in steps:
            cfg = SamplingConfig(num_inference_steps=n, scheduler=sched)
            secs, outs = [], []
            for _ in range(reps):
                t0 = time.perf_counter()
                outs.append(pipe.sample(enc, cfg, seeds=seeds).images)
                secs.append(time.perf_counter() - t0)
            out = outs[-1]
            p = psnr(out, ref)
            finite = p[torch.isfinite(p)]
            row = {
                "scheduler": sched,
                "steps": n,
                # the minimum: other processes share these cores, and they only ever add time
                "s_per_image": round(min(secs) / batch, 5),
                "s_per_image_median": round(float(np.median(secs)) / batch, 5),
                "psnr_vs_ddim50": round(float(finite.mean()), 3) if len(finite) else "inf",
                "perceptual_vs_ddim50": round(float(perceptual(out, ref).mean()), 5),
            }
            rows.append(row)
            common.log(
                f"  {rows[-1]['scheduler']:<12} {n:>3} steps: {row['s_per_image'] * 1000:.1f} ms/img, "
                f"PSNR {row['psnr_vs_ddim50']}, {perceptual.name} {row['perceptual_vs_ddim50']}"
            )
    torch.set_num_threads(threads_before)
    payload = {
        "benchmark": NAME_STEPS,
        "quick": args.quick,
        "config": {
            "model": "tiny preset, random weights (64x64 images)",
            "reference": "DDIM 50 steps, same seeds and conditions",
            "guidance_scale": 3.0,
            "batch": batch,
            "seeds": seeds,
            "conditions": "random images / lighting maps (gaffer_diffusion.testing.random_conditions)",
            "perceptual": perceptual.name,
            "perceptual_note": "stlpips-alex is shift-tolerant LPIPS, not standard LPIPS"
            if perceptual.name == "stlpips-alex"
            else "standard LPIPS (AlexNet)",
            "timing_repetitions": reps,
            "timing_statistic": "minimum over repetitions (shared cores)",
            "torch_threads": 1,
            "caveat": "random-init model: measures convergence to the 50-step DDIM solution, "
            "not relighting quality",
        },
        "machine": meta,
        "rows": rows,
    }
    fig = steps_figure(rows, perceptual.name, {**meta, "torch_threads": 1})
    return [str(p) for p in common.write_results(NAME_STEPS, payload, fig, args.update_baseline)]


def steps_figure(rows: list[dict[str, Any]], pname: str, meta: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    colors = {"ddim": "tab:blue", "dpmsolver++": "tab:orange", "unipc": "tab:green"}
    for sched, color in colors.items():
        rs = [r for r in rows if r["scheduler"] == sched]
        # the 50-step DDIM point is the reference itself (PSNR inf): leave it off the PSNR panel
        pts = [r for r in rs if r["psnr_vs_ddim50"] != "inf"]
        t = [1000 * r["s_per_image"] for r in pts]
        axes[0].plot(t, [r["psnr_vs_ddim50"] for r in pts], "o-", color=color, label=sched)
        for r, x in zip(pts, t, strict=True):
            axes[0].annotate(str(r["steps"]), (x, r["psnr_vs_ddim50"]), fontsize=7)
        t_all = [1000 * r["s_per_image"] for r in rs]
        axes[1].plot(t_all, [r["perceptual_vs_ddim50"] for r in rs], "o-", color=color, label=sched)
        for r, x in zip(rs, t_all, strict=True):
            axes[1].annotate(str(r["steps"]), (x, r["perceptual_vs_ddim50"]), fontsize=7)
    axes[0].set_ylabel("PSNR vs DDIM-50 (dB, higher = closer)")
    axes[1].set_ylabel(f"{pname} vs DDIM-50 (lower = closer)")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("ms per image (CPU, 1 thread, batch 4; labels = steps)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(
        "Steps x scheduler, tiny random-init model, CFG 3 (convergence to DDIM-50, not quality)\n"
        + common.short_device(meta),
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def run_quality(args: argparse.Namespace, meta: dict[str, Any]) -> list[str]:
    from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig
    from gaffer_diffusion.evaluation import EvaluationConfig, dataset_pairs, evaluate_dataset
    from gaffer_diffusion.pretrained import example_dataset_path, gaffer_tiny_path, load_gaffer_tiny
    from gaffer_diffusion.suggested import read_default_sampling

    # guidance, lighting encoding and framing from the model's manifest; steps and scheduler swept
    suggested = read_default_sampling(gaffer_tiny_path())

    schedulers = ("ddim", "dpmsolver++", "unipc")
    steps = (1, 2, 5, 10, 20, 50) if args.quick else (1, 2, 5, 10, 20, 35, 50)
    threads_before = torch.get_num_threads()
    # as in part 2: one thread (comparable across machines) unless --threads asks for more
    threads = args.threads if args.threads > 0 else 1
    torch.set_num_threads(threads)
    pipe = RelightPipeline(load_gaffer_tiny().model, RuntimeConfig(device="cpu", dtype="float32"))
    from gaffer_envmap.bundled import bundled_hdris

    hdri_dir = next(iter(bundled_hdris().values())).parent  # the example was lit by bundled HDRIs
    pairs = dataset_pairs(example_dataset_path(), envmap_dirs=[hdri_dir])
    common.log(f"{NAME_QUALITY}: gaffer-tiny, {len(pairs)} held-out pairs, {schedulers} x {steps}")
    rows, baseline = [], None
    # one untimed pair first, so the first row's seconds do not carry the first call's warm-up
    warm = EvaluationConfig(
        sampling=SamplingConfig(num_inference_steps=1, guidance_scale=suggested.guidance_scale),
        batch_size=1,
        compat=suggested.compat,
        object_fraction=suggested.object_fraction,
    )
    evaluate_dataset(pipe, pairs[:1], warm, perceptual=None)
    # each scheduler over `steps`, then DDIM with mirror averaging (2 UNet passes per step)
    # the multistep solvers need >= 2 steps (SamplingConfig refuses one: a first-order step is DDIM's)
    runs = [(sched, n, False) for sched in schedulers for n in steps if sched == "ddim" or n >= 2]
    runs += [("ddim", n, True) for n in steps if n <= 10]
    for sched, n, mirror in runs:
        cfg = EvaluationConfig(
            sampling=SamplingConfig(
                num_inference_steps=n,
                scheduler=sched,
                guidance_scale=suggested.guidance_scale,
                mirror_average=mirror,
            ),
            batch_size=16,
            baselines=baseline is None,
            compat=suggested.compat,
            object_fraction=suggested.object_fraction,  # the framing it was trained with
        )
        result = evaluate_dataset(pipe, pairs, cfg, perceptual=None)
        if baseline is None:
            baseline = result.baseline
        r = result.report
        rows.append(
            {
                "scheduler": sched + ("+mirror" if mirror else ""),
                "steps": n,
                # sampling + reading + scoring, per pair; one run (the sweep is the repetition)
                "s_per_image": round(result.seconds / len(pairs), 5),
                "object_psnr": round(r.mean_object_raw.psnr, 3) if r.mean_object_raw else None,
                "object_psnr_aligned": round(r.mean_object_aligned.psnr, 3)
                if r.mean_object_aligned
                else None,
                "psnr": round(r.mean_raw.psnr, 3),
                "psnr_aligned": round(r.mean_aligned_image.psnr, 3),
                "ssim": round(r.mean_raw.ssim, 4),
            }
        )
        common.log(
            f"  {rows[-1]['scheduler']:<12} {n:>3} steps: {rows[-1]['s_per_image'] * 1000:.1f} ms/img, "
            f"object PSNR {rows[-1]['object_psnr']} (aligned {rows[-1]['object_psnr_aligned']}), "
            f"full frame {rows[-1]['psnr']}"
        )
    torch.set_num_threads(threads_before)
    assert baseline is not None
    base = {
        "unrelit_input_object_psnr": round(baseline.mean_object_raw.psnr, 3)
        if baseline.mean_object_raw
        else None,
        "unrelit_input_object_psnr_aligned": round(baseline.mean_object_aligned.psnr, 3)
        if baseline.mean_object_aligned
        else None,
        "unrelit_input_psnr": round(baseline.mean_raw.psnr, 3),
        "unrelit_input_ssim": round(baseline.mean_raw.ssim, 4),
        "input_aligned_to_target_psnr": round(baseline.mean_aligned_image.psnr, 3),
    }
    payload = {
        "benchmark": NAME_QUALITY,
        "quick": args.quick,
        "config": {
            "model": "gaffer-tiny (shipped weights, pixel space, 128x128, radiance hints)",
            "steps": list(steps),
            "data": (
                "gaffer_diffusion/data/example: an unseen object, lighting 0 as input, targets "
                "under its other lightings (the 8 bundled HDRIs, 4 of them seen in training), "
                "object-centred 75% crops"
            ),
            "pairs": len(pairs),
            "guidance_scale": suggested.guidance_scale,
            "suggested_sampling": suggested.to_json(),
            "background": "input kept outside its alpha (EvaluationConfig.keep_background)",
            "mirror": "ddim+mirror rows: SamplingConfig.mirror_average (2 UNet passes per step)",
            "seed": 0,
            "torch_threads": threads,
            "timing": (
                "one evaluate_dataset call per row (after one untimed warm-up pair): sampling + "
                "PNG reading + scoring, per pair"
            ),
        },
        # what was measured: the weights' and the example's manifest sha256
        "model": common.model_provenance(),
        "data": common.data_provenance(example_dataset_path()),
        "baselines": base,
        "machine": {**meta, "torch_threads": threads},
        "rows": rows,
    }
    fig = quality_figure(rows, base, {**meta, "torch_threads": threads})
    return [str(p) for p in common.write_results(NAME_QUALITY, payload, fig, args.update_baseline)]


def quality_figure(rows: list[dict[str, Any]], base: dict[str, float], meta: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.4))
    colors = {
        "ddim": "tab:blue",
        "dpmsolver++": "tab:orange",
        "unipc": "tab:green",
        "ddim+mirror": "tab:purple",
    }
    for ax, key, label in (
        (axes[0], "object_psnr", "PSNR over the object mask (dB)"),
        (axes[1], "object_psnr_aligned", "channel-aligned PSNR over the object mask (dB)"),
    ):
        for sched, color in colors.items():
            rs = [r for r in rows if r["scheduler"] == sched]
            if not rs:
                continue
            t = [1000 * r["s_per_image"] for r in rs]
            ax.plot(t, [r[key] for r in rs], "o-", color=color, label=f"gaffer-tiny, {sched}")
            for r, x in zip(rs, t, strict=True):
                ax.annotate(str(r["steps"]), (x, r[key]), fontsize=7)
        ax.axhline(base["unrelit_input_object_psnr"], color="gray", ls="--", label="unrelit input")
        ax.axhline(
            base["unrelit_input_object_psnr_aligned"],
            color="black",
            ls=":",
            label="input channel-aligned to target",
        )
        ax.set_ylabel(label)
        ax.set_xscale("log")
        ax.set_xlabel(f"ms per image (CPU, {meta['torch_threads']} thread(s); labels = steps)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(
        "gaffer-tiny on its example (an unseen object): object-mask quality vs sampling time\n"
        + common.short_device(meta),
        fontsize=9,
    )
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    import gaffer_diffusion

    meta["gaffer_diffusion"] = gaffer_diffusion.__version__
    common.log(f"bench_diffusion: {meta['device']}, torch threads {threads}, quick={args.quick}")
    t0 = time.perf_counter()
    written: list[str] = []
    if args.part in ("all", "steps"):
        written += run_steps(args, meta)
    if args.part in ("all", "quality"):
        written += run_quality(args, meta)
    if args.part in ("all", "speed"):
        written += run_speed(args, meta)
    common.log(f"done in {time.perf_counter() - t0:.0f} s; wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
