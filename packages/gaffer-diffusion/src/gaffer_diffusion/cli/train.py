"""`gaffer-diffusion train`, `export` and `init-random`: training a model (extra [train]), writing
a training checkpoint as a model folder, and saving a random-weight one."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import ConfigError, InputValueError, MissingDependencyError

MODEL_FOLDERS = ("unet", "vae", "image_encoder", "scheduler")
"""The sub-folders of a model folder (`loading.save_pretrained`), beside its manifest."""

TRAIN_FOLDERS = ("checkpoints", "logs", "val", "final")
"""What a training run writes in its `output_dir`."""


def _init_random(args: argparse.Namespace) -> int:
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    checks.writable_dir("--out", args.out, files=[MANIFEST_NAME], folders=MODEL_FOLDERS)
    from gaffer_diffusion.configs import get_preset
    from gaffer_diffusion.loading import save_pretrained
    from gaffer_diffusion.models.build import build_model

    model = build_model(get_preset(args.preset), seed=args.seed)
    save_pretrained(model, args.out)
    print(f"wrote a random-weight {args.preset} model to {args.out}")
    return 0


def _training_module(what: str) -> Any:
    """`gaffer_diffusion.training`, or a clear error naming the `train` extra."""
    try:
        import gaffer_diffusion.training as training
        import gaffer_diffusion.training.loop  # noqa: F401  (accelerate and gaffer-data load here)
    except ImportError as exc:
        raise MissingDependencyError(
            f'{what} needs the train extra ({exc.name} is missing): pip install "gaffer-diffusion[train]"'
        ) from exc
    return training


def _export(args: argparse.Namespace) -> int:
    checks.need_dir(
        "checkpoint", args.checkpoint, "a checkpoint-NNNNNNNN/ folder of a training run"
    )
    checks.writable_dir("--out", args.out)
    if args.out.exists() and any(args.out.iterdir()):
        raise ConfigError(f"`--out` {args.out} exists and is not empty; pass a new folder.")
    load_checkpoint_model = _training_module("Exporting").loop.load_checkpoint_model
    from gaffer_diffusion.loading import save_pretrained

    model = load_checkpoint_model(args.checkpoint, use_ema=not args.raw)
    if args.half:
        import torch

        # a shipped model's file halves (a 15M-parameter UNet: 60 -> 30 MB); every loader copies the
        # tensors into float32 parameters, so only the rounding to float16 remains
        torch.nn.Module.to(model.unet, dtype=torch.float16)
    from gaffer_diffusion.suggested import suggestion_from_training_config
    from gaffer_diffusion.training.checkpoint import read_state

    # the encoding, framing and sampler it was trained and validated with travel with the weights
    suggested = suggestion_from_training_config(read_state(args.checkpoint).config)
    out = save_pretrained(model, args.out, suggested=suggested)
    half = " (UNet in float16)" if args.half else ""
    print(f"wrote {'trained' if args.raw else 'EMA'} weights of {args.checkpoint} to {out}{half}")
    return 0


def _train(args: argparse.Namespace) -> int:
    import json

    checks.need_file(
        "--config", args.config, "a training config JSON (packages/gaffer-diffusion/configs/)"
    )
    try:
        json.loads(args.config.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputValueError(
            f"`--config` {args.config} is not valid JSON ({exc}); fix the file."
        ) from exc
    training = _training_module("Training")
    load_config, train = training.load_config, training.train
    config = load_config(args.config)
    try:  # checkpoints/, logs/, val/ and final/ go in it: checked before any data or model loads
        checks.writable_dir("output_dir", Path(config.output_dir), folders=TRAIN_FOLDERS)
    except ConfigError as exc:
        raise ConfigError(f"`--config` {args.config}: {exc}") from exc
    result = train(config, resume=args.resume)
    print(
        f"trained steps {result.start_step} -> {result.step} ({result.stop_reason}) in "
        f"{result.seconds:.0f} s; checkpoint {result.checkpoint}; final model {result.final_model}"
    )
    for v in result.validations[-1:]:
        print(f"validation PSNR {v.psnr:.2f} dB (unrelit input: {v.psnr_identity:.2f} dB)")
    return 0
