"""The paper-size model on a CPU: the fast path (bf16 + channels-last + SDPA, fewer steps) vs the authors'.

Side by side in one run, on random weights of the paper's shapes (`get_preset("neural-gaffer-256")`:
diffusers `UNet2DConditionModel` with 16 input channels, 859.5M parameters; the SD VAE; CLIP ViT-L/14 at
its real shape; 256x256 images, 32x32 latents; speed does not depend on the weights' values):

- the authors' path: float32 weights, DDIM 50 steps, CFG 3 (one UNet call of batch 2 per step);
- ours: `RuntimeConfig(dtype="auto")` (bf16 weights, channels-last convolutions and the UNet's weights
  packed for oneDNN on a CPU with native bf16, float32 elsewhere; SDPA attention in UNet, VAE and
  CLIP), DDIM 50 or DPM-Solver++ (2M) / UniPC at 15-25 steps;
- each lever alone (UNet step): channels-last in float32, bf16 autocast on float32 weights, bf16
  weights, bf16 weights + channels-last, the UNet's weights packed once for oneDNN
  (`gaffer_diffusion.onednn_weights`), one thread instead of two, the samplers' own arithmetic (a
  stand-in UNet), torch.compile (its own run: `--only compile`);
- the agreement of the fast path with float32 on the same noise and conditions (PSNR between the
  decoded images of a full DPM-Solver++ 20-step sample, both measured end to end), and of the fast
  path's samples (DPM-Solver++ at 15 and 20 steps, UniPC at 15, DDIM 50) with the authors' own
  image (float32 DDIM 50) of the same noise;
- peak memory (RSS) of each path (each role runs in its own process);
- an AVX2-only CPU, emulated on this one by `ONEDNN_MAX_CPU_ISA=AVX2` in a subprocess (oneDNN's
  verbose log is read to check that it took effect);
- gaffer-nerf Stage 1 (`DiffusionGuide.encode_views` + `relight_views`) on a few views, projected to 100:
  float32 DDIM (before) and `auto` with DDIM or with DPM-Solver++ 20 steps (`--scheduler dpmpp-2m`);
- gaffer-tiny (3.8M-parameter UNet, 1 step) in float32 and bf16, and their agreement.

Per-image cost at N steps is extrapolated from measured parts, `encode + N x step + decode` (the
scheduler's arithmetic is negligible beside a UNet call); the end-to-end samples check it. Each role runs
in its own subprocess with `--threads` torch threads (default 2), while the run holds
`/tmp/gaffer-cpu.lock` (as `flock` takes it), so the timings have the shared machine to itself.

Run: `python benchmarks/bench_cpu_fast.py [--update-baseline]` (about 10 minutes on 2 cores), and
`python benchmarks/bench_cpu_fast.py --only compile [--update-baseline]` for torch.compile (its own
run and result file `cpu_fast_compile.json`: compiling the 860M-parameter UNet takes minutes).
"""

import argparse
import fcntl
import functools
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
import torch

NAME = "cpu_fast"
LOCK = "/tmp/gaffer-cpu.lock"
TARGET_50 = 3.0  # >= 3x the authors' per-image time at 50 steps (precision and layout)
TARGET_20 = 8.0  # >= 8x with 20 steps
STEP_GRID = (5, 10, 15, 20, 25, 30, 40, 50)
AGREEMENT_STEPS = 20
STAGE1_VIEWS = 2
STAGE1_STEPS = 10
STAGE1_FAST = ("dpmpp-2m", 20)  # Stage 1 after: gaffer-nerf relight --scheduler dpmpp-2m --steps 20
FEW_STEP_SAMPLES = (("dpmpp-2m", 15), ("unipc", 15))  # besides DPM-Solver++ 20 and DDIM 50


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--update-baseline", action="store_true", help="also write results/cpu_fast.*")
    p.add_argument("--threads", type=int, default=2, help="torch threads of every timed role (2)")
    p.add_argument(
        "--only",
        choices=("compile",),
        help="compile: time torch.compile alone (eager vs compiled UNet step in one process; "
        "writes cpu_fast_compile.*)",
    )
    p.add_argument("--quick", action="store_true", help="accepted for `nox -s bench`; no effect")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--preset", default="neural-gaffer-256", help=argparse.SUPPRESS)  # smoke tests
    p.add_argument("--role", choices=("authors", "fast", "avx2", "compile"), help=argparse.SUPPRESS)
    p.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    return p.parse_args(argv)


# ---------------------------------------------------------------------------------------------
# Roles: each in its own process (peak RSS per path), under the CPU lock
# ---------------------------------------------------------------------------------------------
def _best(fn: Callable[[], object], reps: int, warmup: int = 1) -> float:
    """Minimum seconds over `reps` timed calls after `warmup` untimed ones (other processes only
    ever add time)."""
    with torch.no_grad():
        for _ in range(warmup):
            fn()
        times = []
        for _ in range(reps):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
    return min(times)


def _peak_rss_gib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # KiB on Linux


def _paper_pipe(dtype: str, args: argparse.Namespace) -> Any:
    from gaffer_diffusion import RelightPipeline, RuntimeConfig, build_model, get_preset

    model = build_model(get_preset(args.preset), seed=args.seed)
    return RelightPipeline(model, RuntimeConfig(device="cpu", dtype=dtype))


def _parts(pipe: Any, seed: int, reps: int) -> tuple[dict[str, float], Any, Any]:
    """Encode (one photo + its maps: one batched VAE call and CLIP), one CFG step (UNet batch 2),
    decode (one image): seconds each. Returns the encoded conditions and the UNet inputs too."""
    from gaffer_diffusion.models.model import vae_decode
    from gaffer_diffusion.testing import random_conditions

    cond = random_conditions(1, pipe.model.config.resolution, seed=seed)
    enc = pipe.encode(cond)
    t_enc = _best(lambda: pipe.encode(cond), reps)
    h = pipe.model.config.latent_size
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(2, 4, h, h, generator=g).to(pipe.dtype)
    cat = torch.cat([enc.concat_latents(), torch.zeros_like(enc.concat_latents())])
    ctx = torch.cat([enc.clip_embeds, torch.zeros_like(enc.clip_embeds)])
    x = torch.cat([z, cat.to(pipe.dtype)], dim=1)
    t = torch.tensor(981)

    def step() -> object:
        return pipe._unet(x, t, encoder_hidden_states=ctx.to(pipe.dtype))

    t_step = _best(step, reps + 1)
    t_dec = _best(lambda: vae_decode(pipe.model.vae, z[:1]), reps)
    return {"encode_s": t_enc, "step_s": t_step, "decode_s": t_dec}, (x, t, ctx), cond


def _unet_step(unet: Any, inputs: Any, dtype: torch.dtype, reps: int, warmup: int = 1) -> float:
    x, t, ctx = inputs
    return _best(lambda: unet(x.to(dtype), t, encoder_hidden_states=ctx.to(dtype)), reps, warmup)


def _sample(pipe: Any, cond: Any, steps: int, scheduler: str, seed: int) -> tuple[float, Any]:
    """One full sample (encode, `steps` CFG-3 steps, decode) from the seed's noise: seconds, images."""
    from gaffer_diffusion import SamplingConfig

    cfg = SamplingConfig(num_inference_steps=steps, guidance_scale=3.0, scheduler=scheduler)
    t0 = time.perf_counter()
    with torch.no_grad():
        out = pipe(cond, cfg, seeds=[seed])
    return time.perf_counter() - t0, out.images.float()


def _stage1(
    pipe: Any, seed: int, steps: int = STAGE1_STEPS, scheduler: str = "ddim"
) -> dict[str, Any]:
    """gaffer-nerf Stage 1's relight call (encode the views once, relight them) on a few views at
    `steps` steps of `scheduler` (`DiffusionSamplingConfig.scheduler`, what `gaffer-nerf relight
    --scheduler` sets); the caller projects to 100 views (and DDIM to 50 steps)."""
    from gaffer_diffusion.testing import random_conditions
    from gaffer_nerf.configs import DiffusionSamplingConfig
    from gaffer_nerf.guidance import DiffusionGuide

    sampling = DiffusionSamplingConfig(
        num_inference_steps=steps,
        scheduler=scheduler,  # type: ignore[arg-type]  # one of gaffer_nerf.configs.SAMPLERS
        batch_size=STAGE1_VIEWS,
    )
    guide = DiffusionGuide(pipe, sampling)
    cond = random_conditions(STAGE1_VIEWS, pipe.model.config.resolution, seed=seed)
    t0 = time.perf_counter()
    with torch.no_grad():
        views = guide.encode_views(cond.image, cond.lighting)
        out = guide.relight_views(views)
    seconds = time.perf_counter() - t0
    s = guide.sampling_config()
    return {
        "views": STAGE1_VIEWS,
        "steps": s.num_inference_steps,
        "scheduler": s.scheduler,
        "guidance": s.guidance_scale,
        "mirror_average": s.mirror_average,
        "seconds": seconds,
        "seconds_per_view": seconds / STAGE1_VIEWS,
        "finite": bool(torch.isfinite(out).all()),
    }


def _sampler_overhead(pipe: Any, cond: Any, steps: int, scheduler: str) -> float:
    """Seconds per image of the sampling loop without the UNet: `RelightPipeline.sample`'s own loop
    (CFG batching, scale_model_input, the solver's step, the decode excluded) with a stand-in UNet
    that returns a fixed prediction instantly."""
    from types import SimpleNamespace

    from gaffer_diffusion import SamplingConfig
    from gaffer_diffusion.pipelines import relight

    enc = pipe.encode(cond).to(dtype=pipe.dtype)
    h = pipe.model.config.latent_size
    eps = torch.randn(2, 4, h, h, generator=torch.Generator().manual_seed(1)).to(pipe.dtype)
    z = torch.randn(1, 4, h, h, generator=torch.Generator().manual_seed(2)).to(pipe.dtype)
    stand_in = lambda *a, **k: SimpleNamespace(sample=eps)  # noqa: E731
    cfg = SamplingConfig(num_inference_steps=steps, guidance_scale=3.0, scheduler=scheduler)

    def loop() -> object:
        sched = relight.make_scheduler(cfg.scheduler, pipe.model.config.scheduler)
        sched.set_timesteps(steps)
        x = z * sched.init_noise_sigma
        for t in sched.timesteps:
            x_in = sched.scale_model_input(x, t)
            e = relight._guided_prediction(stand_in, x_in, t, enc, cfg.guidance_scale)
            x = relight._step(sched, e, t, x, eta=0.0, generator=None)
        return x

    return _best(loop, 3)


def _packing_lever(pipe: Any, inputs: Any, reps: int) -> dict[str, Any]:
    """The UNet step with its weights packed for oneDNN (as `auto` runs) vs eager layers, in this
    process, and the largest difference between their outputs."""
    from gaffer_diffusion.onednn_weights import (
        packed_layers,
        prepack_onednn_weights,
        unpack_onednn_weights,
    )

    unet = pipe.model.unet
    x, t, ctx = inputs
    with torch.no_grad():
        packed_out = unet(x.to(pipe.dtype), t, encoder_hidden_states=ctx.to(pipe.dtype)).sample
    n_packed = packed_layers(unet)
    n = unpack_onednn_weights(unet)
    eager = _unet_step(unet, inputs, pipe.dtype, reps)
    with torch.no_grad():
        eager_out = unet(x.to(pipe.dtype), t, encoder_hidden_states=ctx.to(pipe.dtype)).sample
    prepack_onednn_weights(unet)
    packed = _unet_step(unet, inputs, pipe.dtype, reps)
    return {
        "layers": n,
        "layers_packed_by_auto": n_packed,
        "eager_step_s": eager,
        "packed_step_s": packed,
        "max_abs_diff": float((packed_out.float() - eager_out.float()).abs().max()),
    }


def _gaffer_tiny(seed: int, reps: int) -> dict[str, Any]:
    """gaffer-tiny's default sample (its own steps and guidance) in float32 and bf16: seconds per
    image and PSNR between the two."""
    from gaffer_diffusion import RuntimeConfig, load_pipeline
    from gaffer_diffusion.testing import random_conditions

    out: dict[str, Any] = {"weights": "the shipped gaffer-tiny"}
    images = {}
    for dtype in ("float32", "bfloat16"):
        pipe = load_pipeline(None, runtime=RuntimeConfig(dtype=dtype))
        cond = random_conditions(1, pipe.model.config.resolution, seed=seed)
        sampling = pipe.default_sampling.sampling_config()
        with torch.no_grad():
            images[dtype] = pipe(cond, sampling, seeds=[seed]).images.float()
        call = functools.partial(pipe, cond, sampling, seeds=[seed])
        out[f"{dtype}_s_per_image"] = _best(call, reps)
        out["steps"] = sampling.num_inference_steps
    out["auto_resolves_to"] = load_pipeline(
        None, runtime=RuntimeConfig(dtype="auto")
    ).dtype_choice.dtype
    out["psnr_bf16_vs_fp32_db"] = _psnr(images["bfloat16"], images["float32"])
    out["speedup_bf16"] = out["float32_s_per_image"] / out["bfloat16_s_per_image"]
    return out


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(((a - b) ** 2).mean())
    return float("inf") if mse == 0 else 10.0 * float(np.log10(1.0 / mse))


def role_authors(args: argparse.Namespace) -> dict[str, Any]:
    """The authors' path (float32) and the float32 levers."""
    pipe = _paper_pipe("float32", args)
    parts, inputs, cond = _parts(pipe, args.seed, reps=2)
    unet = pipe.model.unet
    levers = {"fp32": parts["step_s"]}
    unet.to(memory_format=torch.channels_last)
    levers["fp32_channels_last"] = _unet_step(unet, inputs, torch.float32, 2)
    unet.to(memory_format=torch.contiguous_format)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        levers["bf16_autocast"] = _unet_step(unet, inputs, torch.float32, 2)
    seconds, images = _sample(pipe, cond, AGREEMENT_STEPS, "dpmpp-2m", args.seed)
    seconds50, images50 = _sample(pipe, cond, 50, "ddim", args.seed)  # the authors' image
    torch.save({"dpmpp-2m-20": images, "ddim-50": images50}, args.out.with_suffix(".pt"))
    return {
        "dtype": str(pipe.runtime.dtype),
        "parts": parts,
        "levers_step_s": levers,
        "sample_dpmpp20_s": seconds,
        "sample_ddim50_s": seconds50,
        "stage1": _stage1(pipe, args.seed),
        "peak_rss_gib": _peak_rss_gib(),
    }


def role_fast(args: argparse.Namespace) -> dict[str, Any]:
    """Ours: `dtype="auto"` (what the CLI runs) and the bf16 levers."""
    pipe = _paper_pipe("auto", args)
    parts, inputs, cond = _parts(pipe, args.seed, reps=2)
    unet = pipe.model.unet
    levers = {"auto": parts["step_s"]}
    packing = None
    if pipe.dtype == torch.bfloat16:
        from gaffer_diffusion.onednn_weights import prepack_onednn_weights, unpack_onednn_weights

        packing = _packing_lever(pipe, inputs, 2)
        unpack_onednn_weights(unet)  # bf16 weights alone: PyTorch's layout, eager layers
        unet.to(memory_format=torch.contiguous_format)
        levers["bf16_contiguous"] = _unet_step(unet, inputs, torch.bfloat16, 2)
        unet.to(memory_format=torch.channels_last)
        prepack_onednn_weights(unet)
    torch.set_num_threads(1)
    levers["auto_1_thread"] = _unet_step(unet, inputs, pipe.dtype, 1)
    torch.set_num_threads(args.threads)
    seconds, images = _sample(pipe, cond, AGREEMENT_STEPS, "dpmpp-2m", args.seed)
    seconds50, images50 = _sample(pipe, cond, 50, "ddim", args.seed)
    saved = {"dpmpp-2m-20": images, "ddim-50": images50}
    few_step_s = {}
    for name, n in FEW_STEP_SAMPLES:
        few_step_s[f"{name}-{n}"], saved[f"{name}-{n}"] = _sample(pipe, cond, n, name, args.seed)
    torch.save(saved, args.out.with_suffix(".pt"))
    overhead = {
        f"{name}-{n}": _sampler_overhead(pipe, cond, n, name)
        for name, n in (("dpmpp-2m", 20), ("ddim", 50))
    }
    return {
        "dtype": str(pipe.runtime.dtype),
        "dtype_reason": pipe.dtype_choice.reason,
        "unet_params": sum(p.numel() for p in unet.parameters()),
        "channels_last": bool(unet.conv_in.weight.is_contiguous(memory_format=torch.channels_last)),
        "parts": parts,
        "levers_step_s": levers,
        "onednn_packing": packing,
        "sample_dpmpp20_s": seconds,
        "sample_ddim50_s": seconds50,
        "samples_s": few_step_s,
        "sampler_overhead_s_per_image": overhead,
        "stage1": _stage1(pipe, args.seed),
        "stage1_fast": _stage1(pipe, args.seed, STAGE1_FAST[1], STAGE1_FAST[0]),
        "peak_rss_gib": _peak_rss_gib(),
        "gaffer_tiny": _gaffer_tiny(args.seed, reps=3),
    }


EMULATED_LIMIT_S = 60


def _too_slow(signum: int, frame: object) -> None:
    raise TimeoutError


def role_avx2(args: argparse.Namespace) -> dict[str, Any]:
    """Under ONEDNN_MAX_CPU_ISA=AVX2: what `auto` picks, float32 parts, and a bf16 step (emulated)."""
    pipe = _paper_pipe("auto", args)
    parts, inputs, _ = _parts(pipe, args.seed, reps=1)
    unet = pipe.model.unet
    unet.to(torch.bfloat16).to(memory_format=torch.channels_last)
    bf16: float | None = None
    signal.signal(signal.SIGALRM, _too_slow)
    signal.alarm(EMULATED_LIMIT_S)  # emulated bf16 can take minutes per step: give up then
    try:
        bf16 = _unet_step(unet, inputs, torch.bfloat16, 1, warmup=0)
    except TimeoutError:
        common.log(f"avx2: a bf16 UNet step took over {EMULATED_LIMIT_S} s; stopped")
    finally:
        signal.alarm(0)
    return {
        "env": {k: os.environ.get(k) for k in AVX2_ENV},
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "dtype": str(pipe.runtime.dtype),
        "dtype_reason": pipe.dtype_choice.reason,
        "parts": parts,
        "levers_step_s": {"auto": parts["step_s"], "bf16_channels_last": bf16},
        "bf16_step_limit_s": EMULATED_LIMIT_S,
        "peak_rss_gib": _peak_rss_gib(),
    }


FP32_IMAGES = common.RUNS / f"{NAME}-float32-images.pt"
"""The float32 role's images of the last full run (git-ignored), for the compile run's agreement."""

COMPILE_FREEZING = True
"""inductor's CPU inference mode: weights folded in as constants and packed for oneDNN
(`torch._inductor.config.freezing`); without it the compiled UNet calls the same unpacked kernels."""


def role_compile(args: argparse.Namespace) -> dict[str, Any]:
    """torch.compile (inductor, default mode, freezing) of the `auto` UNet: compile time from an
    empty cache, step time against the eager UNet as `auto` runs it (weights packed for oneDNN),
    the compiled output's difference, and a second timestep (no recompile expected)."""
    import torch._inductor.config as inductor_config

    from gaffer_diffusion.onednn_weights import packed_layers, unpack_onednn_weights

    inductor_config.freezing = COMPILE_FREEZING
    pipe = _paper_pipe("auto", args)
    _, inputs, cond = _parts(pipe, args.seed, reps=1)
    unet = pipe.model.unet
    eager = _unet_step(unet, inputs, pipe.dtype, 2)
    eager_s, eager_img = _sample(pipe, cond, AGREEMENT_STEPS, "dpmpp-2m", args.seed)
    x, t, ctx = inputs
    x, ctx = x.to(pipe.dtype), ctx.to(pipe.dtype)
    with torch.no_grad():
        ref = unet(x, t, encoder_hidden_states=ctx).sample.float()
    eager_packed = packed_layers(unet)  # `auto` packs them (0 would mean an unpacked baseline)
    unpack_onednn_weights(unet)  # inductor packs the weights itself (freezing)
    compiled = torch.compile(unet)
    t0 = time.perf_counter()
    with torch.no_grad():
        out = compiled(x, t, encoder_hidden_states=ctx).sample.float()
    first = time.perf_counter() - t0
    step = _unet_step(compiled, inputs, pipe.dtype, 2)
    t0 = time.perf_counter()
    with torch.no_grad():
        compiled(x, torch.tensor(501), encoder_hidden_states=ctx)
    other_t = time.perf_counter() - t0
    pipe._unet = compiled  # what RelightPipeline(runtime=RuntimeConfig(compile=True)) calls
    compiled_s, compiled_img = _sample(pipe, cond, AGREEMENT_STEPS, "dpmpp-2m", args.seed)
    agreement: dict[str, Any] = {"compiled_vs_eager_auto_psnr_db": _psnr(compiled_img, eager_img)}
    if FP32_IMAGES.is_file():  # the float32 image of the last full run (same seed and conditions)
        fp32 = torch.load(FP32_IMAGES)["dpmpp-2m-20"]
        agreement["eager_auto_vs_fp32_psnr_db"] = _psnr(eager_img, fp32)
        agreement["compiled_vs_fp32_psnr_db"] = _psnr(compiled_img, fp32)
    return {
        "backend": "inductor",
        "mode": "default",
        "freezing": COMPILE_FREEZING,
        "cache": "empty (TORCHINDUCTOR_CACHE_DIR in a fresh temporary folder)",
        "eager_packed_step_s": eager,
        "eager_layers_packed": eager_packed,
        "compiled_step_s": step,
        "compile_first_call_s": first,
        "second_timestep_call_s": other_t,
        "relative_diff_vs_eager": float((out - ref).norm() / ref.norm()),
        "sample_dpmpp20_eager_s": eager_s,
        "sample_dpmpp20_compiled_s": compiled_s,
        "agreement": {"what": f"DPM-Solver++ {AGREEMENT_STEPS}, CFG 3, same seed", **agreement},
        "peak_rss_gib": _peak_rss_gib(),
    }


ROLES = {"authors": role_authors, "fast": role_fast, "avx2": role_avx2, "compile": role_compile}


# ---------------------------------------------------------------------------------------------
# Orchestration
# ---------------------------------------------------------------------------------------------
def _run_role(
    role: str, args: argparse.Namespace, tmp: Path, env_extra: dict[str, str]
) -> dict[str, Any]:
    threads = args.threads
    out = tmp / f"{role}.json"
    env = {
        **os.environ,
        "OMP_NUM_THREADS": str(threads),
        "MKL_NUM_THREADS": str(threads),
        "PYTHONHASHSEED": "0",
        **env_extra,
    }
    cmd = [sys.executable, __file__, "--role", role, "--out", str(out)]
    cmd += ["--threads", str(threads), "--preset", args.preset, "--seed", str(args.seed)]
    common.log(f"role {role} {env_extra or ''} ...")
    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, check=True)
    common.log(f"role {role}: {time.perf_counter() - t0:.0f} s")
    return json.loads(out.read_text())


def _onednn_isa(env_extra: dict[str, str]) -> dict[str, str]:
    """The oneDNN kernel of a float32 and of a bf16 convolution (ONEDNN_VERBOSE), to check that an
    ISA limit took effect; "not oneDNN" where torch ran its own (emulated) kernel instead."""
    code = (
        "import torch\n"
        "for dt in (torch.float32, torch.bfloat16):\n"
        "    print('dtype', dt, flush=True)\n"
        "    c = torch.nn.Conv2d(64, 64, 3).to(dt)\n"
        "    c(torch.randn(1, 64, 32, 32, dtype=dt))\n"
        "print('capability', torch.backends.cpu.get_cpu_capability())\n"
    )
    env = {**os.environ, "ONEDNN_VERBOSE": "1", "OMP_NUM_THREADS": "1", **env_extra}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=False
    ).stdout
    found: dict[str, str] = {}
    current = None
    for line in out.splitlines():
        if line.startswith("dtype "):
            current = line.split("torch.", 1)[1]
            found[current] = "not oneDNN (torch's own kernel)"
        elif line.startswith("capability "):
            found["torch_cpu_capability"] = line.split(" ", 1)[1]
        elif current and ",convolution," in line:
            found[current] = line.split(",convolution,", 1)[1].split(",", 1)[0]
    return found


AVX2_ENV = {
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "ATEN_CPU_CAPABILITY": "avx2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
}
"""An AVX2-only CPU on this one: oneDNN's kernels, torch's own (ATen) and MKL's all limited to AVX2."""


def per_image(parts: dict[str, float], steps: int) -> float:
    """Seconds per image at `steps` CFG steps: encode + steps x step + decode."""
    return parts["encode_s"] + steps * parts["step_s"] + parts["decode_s"]


def summarize(roles: dict[str, dict[str, Any]], threads: int) -> dict[str, Any]:
    a, f, v = roles["authors"], roles["fast"], roles["avx2"]
    authors50 = per_image(a["parts"], 50)
    fast = {n: per_image(f["parts"], n) for n in STEP_GRID}
    avx2 = {n: per_image(v["parts"], n) for n in STEP_GRID}
    base_step = a["levers_step_s"]["fp32"]
    nan = float("nan")
    packing = f.get("onednn_packing") or {}
    levers = {
        "fp32 channels-last": base_step / a["levers_step_s"]["fp32_channels_last"],
        "bf16 autocast (fp32 weights)": base_step / a["levers_step_s"]["bf16_autocast"],
        "bf16 weights": base_step / f["levers_step_s"].get("bf16_contiguous", nan),
        "bf16 weights + channels-last": base_step / packing.get("eager_step_s", nan),
        "bf16 weights + channels-last + packed oneDNN weights (auto)": base_step
        / f["levers_step_s"]["auto"],
        "packed oneDNN weights alone (bf16 step, eager / packed)": packing.get("eager_step_s", nan)
        / packing.get("packed_step_s", nan),
        "auto, 1 thread instead of 2": base_step / f["levers_step_s"]["auto_1_thread"],
        "encode (VAE + CLIP)": a["parts"]["encode_s"] / f["parts"]["encode_s"],
        "decode (VAE)": a["parts"]["decode_s"] / f["parts"]["decode_s"],
        "DPM-Solver++ 20 steps instead of DDIM 50": per_image(f["parts"], 50) / fast[20],
    }
    s1a, s1f, s1x = a["stage1"], f["stage1"], f["stage1_fast"]

    def stage1_projection(stage: dict[str, Any], parts: dict[str, float]) -> float:
        # measured seconds per view at STAGE1_STEPS, plus the remaining steps at the measured
        # per-step cost of one view (CFG batch 2), times 100 views
        extra = (50 - stage["steps"]) * parts["step_s"]
        return 100 * (stage["seconds_per_view"] + extra)

    return {
        "per_image_s": {
            "authors_fp32_ddim50": authors50,
            "fast_ddim50": fast[50],
            "fast_dpmpp20": fast[20],
            "fast_dpmpp15": fast[15],
            "fast_dpmpp25": fast[25],
            "fast_dpmpp15_unipc15": fast[15],
            "avx2_fp32_ddim50": avx2[50],
            "avx2_fp32_dpmpp20": avx2[20],
        },
        "speedup_vs_authors": {
            "fast_ddim50": authors50 / fast[50],
            "fast_dpmpp20": authors50 / fast[20],
            "fast_dpmpp15": authors50 / fast[15],
            "avx2_fp32_dpmpp20": authors50 / avx2[20],
        },
        "to_target_20": {
            "what": "seconds per image at 20 steps that 8x needs, and how far the fast path is",
            "target_s": authors50 / TARGET_20,
            "fast_dpmpp20_s": fast[20],
            "missing_s": fast[20] - authors50 / TARGET_20,
            "unet_share": 20 * f["parts"]["step_s"] / fast[20],
            "sampler_overhead_share": f["sampler_overhead_s_per_image"]["dpmpp-2m-20"] / fast[20],
        },
        "targets": {
            "ddim50_min_speedup": TARGET_50,
            "dpmpp20_min_speedup": TARGET_20,
            "ddim50_met": authors50 / fast[50] >= TARGET_50,
            "dpmpp20_met": authors50 / fast[20] >= TARGET_20,
        },
        "lever_ratios": levers,
        "time_vs_steps_s": {
            "steps": list(STEP_GRID),
            "authors_fp32": [per_image(a["parts"], n) for n in STEP_GRID],
            "fast_auto": [fast[n] for n in STEP_GRID],
            "avx2_auto_fp32": [avx2[n] for n in STEP_GRID],
        },
        "extrapolation_check": {
            "fast_dpmpp20_measured_s": f["sample_dpmpp20_s"],
            "fast_dpmpp20_extrapolated_s": fast[20],
            "fast_ddim50_measured_s": f["sample_ddim50_s"],
            "fast_ddim50_extrapolated_s": fast[50],
            "authors_fp32_dpmpp20_measured_s": a["sample_dpmpp20_s"],
            "authors_fp32_dpmpp20_extrapolated_s": per_image(a["parts"], 20),
            "authors_fp32_ddim50_measured_s": a["sample_ddim50_s"],
            "fast_samples_measured_s": f["samples_s"],
        },
        "stage1_100_views_projected_s": {
            "before_fp32_ddim50": stage1_projection(s1a, a["parts"]),
            "after_auto_ddim50": stage1_projection(s1f, f["parts"]),
            # measured at its full 20 steps: only the number of views is projected
            f"after_auto_{s1x['scheduler'].replace('-', '')}_{s1x['steps']}": 100
            * s1x["seconds_per_view"],
        },
        "threads": threads,
    }


def plot(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = payload["summary"]["time_vs_steps_s"]
    fig, ax = plt.subplots(figsize=(7.5, 4.5))
    ax.plot(s["steps"], s["authors_fp32"], "o-", label="float32 (authors' precision)")
    ax.plot(s["steps"], s["fast_auto"], "o-", label=f"auto: {payload['roles']['fast']['dtype']}")
    ax.plot(s["steps"], s["avx2_auto_fp32"], "s--", label="auto on AVX2 only (emulated: float32)")
    a50 = payload["summary"]["per_image_s"]["authors_fp32_ddim50"]
    ax.axhline(a50, color="gray", lw=0.8, ls=":")
    ax.annotate("authors: float32, DDIM 50, CFG 3", (5, a50), va="bottom", fontsize=8)
    chk = payload["summary"]["extrapolation_check"]
    ax.plot(
        [20, 50, 20, 50],
        [
            chk["fast_dpmpp20_measured_s"],
            chk["fast_ddim50_measured_s"],
            chk["authors_fp32_dpmpp20_measured_s"],
            chk["authors_fp32_ddim50_measured_s"],
        ],
        "kx",
        label="measured end to end",
    )
    ax.set_xlabel("denoising steps (CFG 3: one UNet call of batch 2 each)")
    ax.set_ylabel("seconds per 256x256 image")
    ax.set_ylim(bottom=0)
    ax.legend(fontsize=8)
    ax.set_title(
        "Paper-size model (random weights) on a CPU\n" + common.short_device(payload["machine"]),
        fontsize=8,
    )
    return fig


def markdown(payload: dict[str, Any]) -> str:
    s = payload["summary"]
    p, x = s["per_image_s"], s["speedup_vs_authors"]
    rows = [
        "| path | seconds per image | vs the authors' |",
        "|---|---:|---:|",
        f"| authors: float32, DDIM 50, CFG 3 | {p['authors_fp32_ddim50']:.1f} | 1.0x |",
        f"| ours (auto: {payload['roles']['fast']['dtype']}), DDIM 50 | {p['fast_ddim50']:.1f} | "
        f"{x['fast_ddim50']:.1f}x |",
        f"| ours, DPM-Solver++ 20 | {p['fast_dpmpp20']:.1f} | {x['fast_dpmpp20']:.1f}x |",
        f"| ours, DPM-Solver++ or UniPC 15 | {p['fast_dpmpp15']:.1f} | {x['fast_dpmpp15']:.1f}x |",
        f"| AVX2-only (float32), DPM-Solver++ 20 | {p['avx2_fp32_dpmpp20']:.1f} | "
        f"{x['avx2_fp32_dpmpp20']:.1f}x |",
    ]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.role is not None:
        common.set_threads(args.threads)
        result = ROLES[args.role](args)
        args.out.write_text(json.dumps(result, indent=2))
        return 0
    common.log(f"waiting for {LOCK} (held for the whole run: every role is timed alone) ...")
    with open(LOCK, "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _measure(args)


def _measure_compile(args: argparse.Namespace) -> int:
    """`--only compile`: torch.compile's role alone (its compile takes minutes), own result file."""
    meta = common.machine(args.threads)
    with tempfile.TemporaryDirectory(prefix="bench_cpu_fast-") as tmp_name:
        tmp = Path(tmp_name)
        cache = {"TORCHINDUCTOR_CACHE_DIR": str(tmp / "inductor")}
        c = _run_role("compile", args, tmp, cache)
    saved = c["eager_packed_step_s"] - c["compiled_step_s"]
    fast20 = json.loads((common.RESULTS / f"{NAME}.json").read_text())["summary"]["per_image_s"]
    payload = {
        "benchmark": f"{NAME}_compile",
        "machine": meta,
        "model": {
            "preset": args.preset,
            "weights": f"random (build_model seed {args.seed}); speed does not depend on values",
        },
        "method": "one process under flock /tmp/gaffer-cpu.lock: the `auto` UNet step (bf16, "
        "channels-last, packed oneDNN weights) eager, then torch.compile of the same UNet; minimum "
        "of repeated calls after a warm-up; compile time is the first compiled call from an empty "
        "inductor cache",
        "role": c,
        "summary": {
            "compiled_vs_eager_step": c["eager_packed_step_s"] / c["compiled_step_s"],
            "compile_s": c["compile_first_call_s"],
            "saved_s_per_20_step_image": 20 * saved,
            "images_to_amortise_compile": c["compile_first_call_s"] / (20 * saved)
            if saved > 0
            else None,
            "fast_dpmpp20_s_per_image_eager": fast20["fast_dpmpp20"],
        },
    }
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.2))
    ax.bar(["eager (auto)", "torch.compile"], [c["eager_packed_step_s"], c["compiled_step_s"]])
    ax.set_ylabel("seconds per CFG step (UNet batch 2)")
    ax.set_title(
        f"compile: {c['compile_first_call_s']:.0f} s once\n" + common.short_device(meta), fontsize=8
    )
    for path in common.write_results(f"{NAME}_compile", payload, fig, args.update_baseline):
        common.log(f"wrote {path}")
    print(json.dumps(payload["summary"], indent=1))
    return 0


AGREEMENT_VS_AUTHORS = ("ddim-50", "dpmpp-2m-20", "dpmpp-2m-15", "unipc-15")


def _measure(args: argparse.Namespace) -> int:
    if args.only == "compile":
        return _measure_compile(args)
    meta = common.machine(args.threads)
    with tempfile.TemporaryDirectory(prefix="bench_cpu_fast-") as tmp_name:
        tmp = Path(tmp_name)
        roles = {
            "authors": _run_role("authors", args, tmp, {}),
            "fast": _run_role("fast", args, tmp, {}),
            "avx2": _run_role("avx2", args, tmp, AVX2_ENV),
        }
        a_imgs = torch.load(tmp / "authors.pt")
        f_imgs = torch.load(tmp / "fast.pt")
    common.RUNS.mkdir(parents=True, exist_ok=True)
    torch.save(a_imgs, FP32_IMAGES)
    a_img, f_img = a_imgs["dpmpp-2m-20"], f_imgs["dpmpp-2m-20"]
    authors50 = a_imgs["ddim-50"]
    agreement = {
        "what": f"PSNR between the decoded images of a full DPM-Solver++ {AGREEMENT_STEPS}-step "
        "sample, CFG 3, same seed and conditions: auto vs float32",
        "psnr_db": _psnr(f_img, a_img),
        "max_abs_diff": float((f_img - a_img).abs().max()),
        "vs_authors_fp32_ddim50_psnr_db": {
            "what": "PSNR of each sample (same seed, noise and conditions, CFG 3) against the "
            "authors' float32 DDIM 50 image; random weights: this measures how closely the "
            "samplers and precisions follow the same trajectory, not image quality",
            **{f"auto {k}": _psnr(f_imgs[k], authors50) for k in AGREEMENT_VS_AUTHORS},
            "float32 dpmpp-2m-20": _psnr(a_img, authors50),
        },
    }
    isa = {
        "native": _onednn_isa({}),
        "avx2_env": _onednn_isa(AVX2_ENV),
    }
    payload = {
        "benchmark": NAME,
        "machine": meta,
        "cpu_flags_bf16": [f for f in ("amx_bf16", "avx512_bf16") if f in _flags()],
        "onednn_isa_reported": isa,
        "model": {
            "preset": args.preset,
            "weights": f"random (build_model seed {args.seed}); speed does not depend on values",
            "unet_params": roles["fast"]["unet_params"],
        },
        "method": "per-image seconds = encode + steps x (one CFG step: UNet batch 2) + decode, from "
        "the minimum of repeated timed calls after a warm-up; end-to-end samples check the sum. "
        "Each role is its own process under flock /tmp/gaffer-cpu.lock; peak RSS per process.",
        "roles": roles,
        "agreement": agreement,
        "summary": summarize(roles, args.threads),
    }
    fig = plot(payload)
    for path in common.write_results(NAME, payload, fig, args.update_baseline):
        common.log(f"wrote {path}")
    print(markdown(payload))
    print(json.dumps(payload["summary"], indent=1))
    return 0


def _flags() -> frozenset[str]:
    from gaffer_diffusion.runtime_dtype import cpu_flags

    return cpu_flags()


if __name__ == "__main__":
    sys.exit(main())
