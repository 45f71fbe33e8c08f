"""Helpers the model commands share: loading the networks through `load_pipeline`, the torch device,
and writing PNGs, progress bars and input folders. torch is imported only inside the functions that
need it."""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion.errors import ConfigError, InputValueError

if TYPE_CHECKING:
    import numpy as np
    import torch
    from tqdm import tqdm

    from gaffer_diffusion.models.model import NeuralGafferModel

logger = logging.getLogger("gaffer_diffusion.cli")  # the name log lines carried before the split


def _load_model(checkpoint: Path | None, base_model: Path | None) -> NeuralGafferModel:
    """The networks `load_pipeline` loads (float32, CPU), for commands that build their own pipeline."""
    from gaffer_diffusion.pipelines import load_pipeline

    return load_pipeline(checkpoint, base_model).model


def _base_model_error(checkpoint: Path) -> ConfigError:
    from gaffer_diffusion.pretrained import not_our_folder_message

    return ConfigError(not_our_folder_message(checkpoint, "--checkpoint", "--base-model"))


def _device_name(device: str | None, *, check: bool = True) -> str:
    """`--device`, else cuda when torch sees a GPU, else cpu; with `check`, a CUDA or MPS device this
    torch cannot use is refused (called before the weights load)."""
    import torch

    if device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if not check:
        return device
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(
            f"`--device {device}`: this torch build ({torch.__version__}) sees no CUDA GPU; pass "
            "`--device cpu`, or install a CUDA build of torch on a machine with a GPU."
        )
    if device.startswith("mps") and not torch.backends.mps.is_available():
        raise ConfigError(f"`--device {device}`: no Apple MPS device here; pass `--device cpu`.")
    return device


def _save_png(path: Path, image: torch.Tensor | np.ndarray) -> None:
    """Write a `[C, H, W]` tensor or an `[H, W(, C)]` array as a PNG, complete or absent
    (`gaffer_envmap.writers.write_png`: uint8 as is, floats on its one 8-bit grid)."""
    import numpy as np

    from gaffer_envmap.writers import write_png

    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, image if isinstance(image, np.ndarray) else image.permute(1, 2, 0))


def _progress(total: int, desc: str) -> tqdm[Any]:
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="img", file=sys.stderr)


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp")


_ENVMAP_SUFFIXES = (".exr", ".hdr")


def _files(folder: Path, suffixes: tuple[str, ...], what: str, flag: str) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)
    if not files:
        raise InputValueError(
            f"`{flag}` {folder} holds no {what} ({', '.join(suffixes)} files directly in it)."
        )
    return files
