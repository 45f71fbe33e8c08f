"""Helpers every model command shares: loading the model (`--checkpoint`, `--base-model`) through
`load_pipeline`, the model's own sampling with the flags given as overrides (`DefaultSampling`), the
torch device and precision, and writing PNGs, progress bars and input folders. torch is imported only
inside the functions that need it."""

from __future__ import annotations

import argparse
import logging
import sys
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import ConfigError, InputValueError
from gaffer_diffusion.suggested import DefaultSampling, read_default_sampling

if TYPE_CHECKING:
    import numpy as np
    import torch
    from tqdm import tqdm

    from gaffer_diffusion.models.model import NeuralGafferModel
    from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig, SamplingConfig

logger = logging.getLogger("gaffer_diffusion.cli")  # the name log lines carried before the split


def _load_pipeline(args: argparse.Namespace) -> RelightPipeline:
    """`--checkpoint` (ours or, with `--base-model`, the authors'), else gaffer-tiny, on `_runtime`."""
    from gaffer_diffusion.pipelines import load_pipeline

    return load_pipeline(args.checkpoint, args.base_model, runtime=_runtime(args))


def _load_model(checkpoint: Path | None, base_model: Path | None) -> NeuralGafferModel:
    """The networks `load_pipeline` loads (float32, CPU), for commands that build their own pipeline."""
    from gaffer_diffusion.pipelines import load_pipeline

    return load_pipeline(checkpoint, base_model).model


def _base_model_error(checkpoint: Path) -> ConfigError:
    from gaffer_diffusion.pretrained import not_our_folder_message

    return ConfigError(not_our_folder_message(checkpoint, "--checkpoint", "--base-model"))


def _defaults(args: argparse.Namespace) -> DefaultSampling:
    """The model's own sampling (`DefaultSampling`): the shipped gaffer-tiny's without `--checkpoint`,
    else what the model folder records (the paper's for the authors' release or a folder that records
    none). A JSON read, no torch, once per folder and manifest version (`_read_defaults`)."""
    from gaffer_diffusion import pretrained

    checkpoint = getattr(args, "checkpoint", None)
    folder = pretrained.gaffer_tiny_path() if checkpoint is None else Path(checkpoint).expanduser()
    manifest = folder / MANIFEST_NAME
    return _read_defaults(str(folder), manifest.stat().st_mtime_ns if manifest.is_file() else 0)


@lru_cache(maxsize=8)
def _read_defaults(folder: str, _manifest_mtime_ns: int) -> DefaultSampling:
    return read_default_sampling(Path(folder))


def _overridden(args: argparse.Namespace) -> DefaultSampling:
    """`_defaults` with every sampling flag the user gave (`--steps`, `--guidance`, ...)."""
    return _defaults(args).override(
        num_inference_steps=getattr(args, "steps", None),
        guidance_scale=getattr(args, "guidance", None),
        average_samples=getattr(args, "average_samples", None),
        mirror_average=getattr(args, "mirror_average", None),
        compat=getattr(args, "compat", None),
    )


def _compat(args: argparse.Namespace) -> Any:
    """`--compat`, else the lighting encoding the model was trained with (`_defaults`)."""
    return args.compat if args.compat is not None else _defaults(args).compat


def _object_fraction(args: argparse.Namespace) -> float | None:
    if args.object_fraction is not None:
        if not 0.0 < args.object_fraction <= 1.0:
            raise ConfigError(
                f"`--object-fraction` is {args.object_fraction}; pass a fraction in (0, 1], e.g. 0.75."
            )
        return float(args.object_fraction)
    return _defaults(args).object_fraction


def _sampling(args: argparse.Namespace) -> SamplingConfig:
    """Every value the user leaves out is the model's own (its folder's `suggested_sampling`); an
    explicit 0 is refused by `SamplingConfig` (it used to mean "the default" silently)."""
    return _overridden(args).sampling_config(
        latent_mode=_latent_mode(args), scheduler=args.scheduler
    )


def _latent_mode(args: argparse.Namespace) -> Any:
    """`--latent-mode`, else the one `--compat` (or the model's encoding) brings (`latent_mode_for`)."""
    if args.latent_mode is not None:
        return args.latent_mode
    return _overridden(args).latent_mode


def _runtime(args: argparse.Namespace) -> RuntimeConfig:
    """Device and precision; `--dtype float16` on CUDA under `--compat neural-gaffer` autocasts the
    UNet with float32 weights, as the authors run it (official implementation §2)."""
    from gaffer_diffusion.pipelines import RuntimeConfig

    _check_autocast(args)
    device = _device(args, check=False)  # checked before the weights load (_load_model callers)
    autocast = args.autocast
    if autocast is None:
        autocast = (
            args.dtype == "float16"
            and device.startswith("cuda")
            and _compat(args) == "neural-gaffer"
        )
    return RuntimeConfig(device=device, dtype=args.dtype, autocast=bool(autocast))


def _check_autocast(args: argparse.Namespace) -> None:
    if args.autocast and args.dtype in ("float32", "auto"):
        raise ConfigError(
            f"`--autocast` with `--dtype {args.dtype}`: autocast runs the UNet in a lower precision "
            "named by --dtype: add `--dtype float16` (the authors') or `--dtype bfloat16`."
        )


def _device(args: argparse.Namespace, *, check: bool = True) -> str:
    """`--device`, else cuda when available; with `check`, a CUDA device this torch cannot use is
    refused."""
    import torch

    if args.device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    device = str(args.device)
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
