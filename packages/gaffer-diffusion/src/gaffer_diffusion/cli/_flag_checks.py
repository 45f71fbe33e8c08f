"""Cheap checks several commands share: the sampling flags, `--device`, and `--checkpoint` with
`--base-model`, all refused before torch is imported or a model loaded (issue 17)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.cli._common import _base_model_error, _check_autocast
from gaffer_diffusion.errors import ConfigError


def _check_checkpoint_args(checkpoint: Path | None, base_model: Path | None) -> None:
    """The checkpoint flags' consistency, checked before any input is read or weight loaded."""
    if checkpoint is None or (checkpoint / MANIFEST_NAME).is_file() or base_model is not None:
        return
    raise _base_model_error(checkpoint)


_DEVICE_NAMES = ("cpu", "cuda", "mps", "xpu")


def _check_device_cheaply(device: str | None) -> None:
    """`--device` names a torch device, and a CUDA one has a GPU to run on (no torch import: a
    Linux machine without /dev/nvidia* has no CUDA device; torch confirms it later)."""
    if device is None:
        return
    kind, _, index = device.partition(":")
    if kind not in _DEVICE_NAMES or (index and not index.isdigit()):
        raise ConfigError(f"`--device` is {device!r}; expected cpu, cuda, cuda:N or mps.")
    if kind == "cuda" and sys.platform.startswith("linux"):
        if not any(Path("/dev").glob("nvidia[0-9]*")):
            raise ConfigError(
                f"`--device {device}`: this machine has no NVIDIA GPU (no /dev/nvidia*); pass "
                "`--device cpu`."
            )


def _check_sampling_args(args: argparse.Namespace) -> None:
    checks.int_range("--steps", args.steps, 1, checks.MAX_STEPS, "gaffer-tiny: 1, the paper: 50")
    checks.finite("--guidance", args.guidance, 0.0, 100.0)
    checks.int_range("--average-samples", args.average_samples, 1, checks.MAX_AVERAGE_SAMPLES)
    checks.int_range("--batch-size", args.batch_size, 1, checks.MAX_BATCH)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    _check_device_cheaply(args.device)
    if hasattr(args, "autocast"):
        _check_autocast(args)


def _check_model_args(args: argparse.Namespace) -> None:
    """`--checkpoint` / `--base-model` exist and go together."""
    if args.checkpoint is not None:
        checks.need_dir(
            "--checkpoint",
            args.checkpoint,
            "a model folder (gaffer_model.json) or checkpoint-80000/",
        )
    base = getattr(args, "base_model", None)
    if base is not None:
        checks.need_dir("--base-model", base, "a local Zero-1-to-3 XL diffusers folder")
    _check_checkpoint_args(args.checkpoint, base)
