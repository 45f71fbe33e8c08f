"""`gaffer-diffusion demo`: the shipped example object relit under the bundled HDRIs and a
turntable (the work is `gaffer_diffusion.demo`; this checks the flags and reports)."""

from __future__ import annotations

import argparse

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.cli._common import _device_name
from gaffer_diffusion.cli._flag_checks import _check_device_cheaply
from gaffer_diffusion.errors import ConfigError


def _validate_demo(args: argparse.Namespace) -> None:
    checks.replaceable_dir("--out", args.out)
    if args.checkpoint is not None:
        checks.need_dir("--checkpoint", args.checkpoint, "a model folder in our format")
        if not (args.checkpoint / MANIFEST_NAME).is_file():
            raise ConfigError(
                f"`--checkpoint` {args.checkpoint} has no {MANIFEST_NAME}: the demo takes a model "
                "folder in our format (`gaffer-diffusion export` or `init-random` writes one)."
            )
    if args.example is not None:
        checks.need_dir("--example", args.example, "a gaffer-data render folder")
    checks.int_range("--steps", args.steps, 1, checks.MAX_STEPS, "gaffer-tiny: 1, the paper: 50")
    checks.finite("--guidance", args.guidance, 0.0, 100.0)
    checks.int_range("--average-samples", args.average_samples, 1, checks.MAX_AVERAGE_SAMPLES)
    checks.int_range("--frames", args.frames, 0, checks.MAX_FRAMES, "0: no turntable; e.g. 24")
    checks.finite("--fps", args.fps, 0.0, checks.MAX_FPS, lo_open=True)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    checks.int_range("--batch-size", args.batch_size, 1, checks.MAX_BATCH)
    checks.int_range("--threads", args.threads, 1, 1024, "torch CPU threads; 1 is best here")
    if args.object_fraction is not None:
        checks.finite("--object-fraction", args.object_fraction, 0.0, 1.0, lo_open=True)
    if args.turntable_hdri is not None:
        from gaffer_envmap.bundled import bundled_hdris

        names = sorted(bundled_hdris())
        if args.turntable_hdri not in names:
            raise ConfigError(
                f"`--turntable-hdri` is {args.turntable_hdri!r}; pass one of the bundled HDRIs: "
                f"{', '.join(names)}."
            )
    _check_device_cheaply(args.device)


def _demo(args: argparse.Namespace) -> int:
    _validate_demo(args)
    import torch

    from gaffer_diffusion.demo import DemoConfig, run_demo

    torch.set_num_threads(args.threads)
    config = DemoConfig(
        out=args.out,
        checkpoint=args.checkpoint,
        example=args.example,
        num_inference_steps=args.steps,
        guidance_scale=args.guidance,
        average_samples=args.average_samples,
        mirror_average=args.mirror_average,
        frames=args.frames,
        turntable_hdri=args.turntable_hdri,
        fps=args.fps,
        seed=args.seed,
        batch_size=args.batch_size,
        device=_device_name(args.device),
        extra_hdris=not args.no_extra_hdris,
        keep_background=not args.full_frame,
        compat=args.compat,
        object_fraction=args.object_fraction,
        sanitize=args.sanitize,
    )
    result = run_demo(config)
    gif = f", {result.turntable_gif}" if result.turntable_gif is not None else ""
    print(
        f"relit {result.images} images in {result.seconds:.1f} s; wrote {result.report_html}, "
        f"{result.metrics_json}{gif} and the PNGs under {result.out}\n"
        f"{result.summary}"
    )
    return 0
