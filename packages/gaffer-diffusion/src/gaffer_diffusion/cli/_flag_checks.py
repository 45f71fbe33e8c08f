"""Cheap checks several commands share, on values (not on the parsed arguments): `--device`, and
`--checkpoint` with `--base-model`, both refused before torch is imported or a model loaded."""

from __future__ import annotations

import sys
from pathlib import Path

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.cli._common import _base_model_error
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
