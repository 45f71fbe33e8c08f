"""`gaffer-diffusion app` options: one frozen `AppConfig`, checked before Gradio or torch models load.

Safe defaults, since the page runs jobs and keeps files for whoever reaches it: the server binds
127.0.0.1 unless `--host` is given, uploads, image sides and pixel counts are bounded, one relighting
job runs at a time behind a bounded queue (a request beyond it is refused, not buffered), and uploaded
files older than `--cache-max-age` are deleted (a long-running server would otherwise fill its disk).
"""

import argparse
import math
from dataclasses import dataclass, field
from pathlib import Path

from gaffer_diffusion._choices import MANIFEST_NAME  # torch-free (loading imports diffusers)
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.runtime_dtype import DTYPE_REQUESTS, DtypeRequest  # torch-free

GAFFER_TINY_LABEL = "gaffer-tiny (shipped)"
"""The model picker's default entry, the model shipped inside the package."""


@dataclass(frozen=True, kw_only=True)
class ModelChoice:
    """One entry of the model picker.

    Attributes:
        label: what the picker shows.
        checkpoint: our model folder (with `gaffer_model.json`) or the authors' `checkpoint-80000/`;
            None for the shipped gaffer-tiny.
        base_model: the local Zero-1-to-3 XL folder an authors' checkpoint needs; None otherwise.
    """

    label: str
    checkpoint: Path | None = None
    base_model: Path | None = None


@dataclass(frozen=True, kw_only=True)
class AppConfig:
    """Everything `gaffer-diffusion app` needs; invalid values raise `ConfigError` naming the flag.

    Attributes:
        host: interface to bind; 127.0.0.1 (this machine only) unless the user asks otherwise.
        port: TCP port (0 < port < 65536).
        models: the model picker's entries, gaffer-tiny first.
        device: torch device for sampling.
        dtype: the networks' precision, as `gaffer-diffusion relight --dtype` takes it ("auto":
            bfloat16 on a CPU with native bf16 for a 100M+ parameter UNet, else float32).
        threads: torch CPU threads, or None for torch's default.
        max_upload_mb: largest accepted upload, per file (Gradio refuses bigger ones in the page).
        max_image_side: largest accepted side of an uploaded photo or environment map, in pixels.
        max_megapixels: largest accepted photo or mask, in millions of pixels (width x height): a
            relight holds several float copies of the photo at full size, so memory follows it.
        queue_size: relight/turntable requests that may wait behind the running one.
        max_frames: most turntable frames one request may ask for.
        max_turntable_side: longest side of a full-size turntable's frames, pixels: a larger photo
            is shrunk to it before its frames are pasted back (a single relight is never shrunk).
        cache_max_age_s: uploads and results older than this many seconds are deleted while the
            server runs (checked every `cache_sweep_s`); everything goes when it stops.
    """

    host: str = "127.0.0.1"
    port: int = 7860
    models: tuple[ModelChoice, ...] = field(
        default_factory=lambda: (ModelChoice(label=GAFFER_TINY_LABEL),)
    )
    device: str = "cpu"
    dtype: DtypeRequest = "auto"
    threads: int | None = None
    max_upload_mb: float = 20.0
    max_image_side: int = 4096
    max_megapixels: float = 16.8
    queue_size: int = 16
    max_frames: int = 48
    max_turntable_side: int = 512
    cache_max_age_s: int = 3600

    def __post_init__(self) -> None:
        if not 0 < self.port < 65536:
            raise ConfigError(f"`--port` is {self.port}; pass a TCP port in 1..65535, e.g. 7860.")
        if not self.host:
            raise ConfigError("`--host` is empty; pass an address to bind, e.g. 127.0.0.1.")
        if not self.models:
            raise ConfigError("The model picker is empty; pass `--model DIR` or keep gaffer-tiny.")
        labels = [m.label for m in self.models]
        if len(set(labels)) != len(labels):
            raise ConfigError(f"Two `--model` entries share a name ({labels}); rename a folder.")
        if self.dtype not in DTYPE_REQUESTS:
            raise ConfigError(
                f"`--dtype` is {self.dtype!r}; expected one of {', '.join(DTYPE_REQUESTS)}."
            )
        if self.threads is not None and self.threads < 1:
            raise ConfigError(f"`--threads` is {self.threads}; expected >= 1.")
        if not (math.isfinite(self.max_upload_mb) and self.max_upload_mb > 0):
            raise ConfigError(f"`--max-upload-mb` is {self.max_upload_mb}; expected > 0, e.g. 20.")
        if self.max_image_side < 64:
            raise ConfigError(f"`--max-image-side` is {self.max_image_side}; expected >= 64.")
        if not (math.isfinite(self.max_megapixels) and self.max_megapixels > 0):
            raise ConfigError(
                f"`--max-image-megapixels` is {self.max_megapixels}; expected > 0, e.g. 16.8."
            )
        if self.cache_max_age_s < 1:
            raise ConfigError(
                f"`--cache-max-age` is {self.cache_max_age_s}; expected >= 1 second, e.g. 3600."
            )
        if self.queue_size < 1:
            raise ConfigError(f"`--queue-size` is {self.queue_size}; expected >= 1.")
        if self.max_frames < 2:
            raise ConfigError(f"`--max-frames` is {self.max_frames}; expected >= 2.")
        if self.max_turntable_side < 16:
            raise ConfigError(
                f"`--max-turntable-side` is {self.max_turntable_side}; expected >= 16, e.g. 512."
            )

    @property
    def max_upload_bytes(self) -> int:
        """`max_upload_mb` in bytes (Gradio's `max_file_size`)."""
        return int(self.max_upload_mb * 1024 * 1024)

    @property
    def max_image_pixels(self) -> int:
        """`max_megapixels` as a pixel count."""
        return int(self.max_megapixels * 1_000_000)

    @property
    def cache_sweep_s(self) -> int:
        """How often old cached files are looked for: a quarter of their lifetime, at most a minute."""
        return max(1, min(60, self.cache_max_age_s // 4))


def add_app_arguments(p: argparse.ArgumentParser) -> None:
    """The `gaffer-diffusion app` flags (argparse only: no Gradio import, so `--help` stays fast)."""
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="interface to bind (default 127.0.0.1: this machine only; 0.0.0.0 exposes the app to "
        "your network, with no authentication)",
    )
    p.add_argument("--port", type=int, default=7860, help="TCP port (default 7860)")
    p.add_argument(
        "--model",
        type=Path,
        action="append",
        default=[],
        help="add a model to the picker: our model folder, or the authors' checkpoint-80000/ with "
        "--base-model (repeatable; gaffer-tiny is always there and the default)",
    )
    p.add_argument(
        "--base-model", type=Path, help="Zero-1-to-3 XL folder for an authors' --model checkpoint"
    )
    p.add_argument(
        "--device", help="torch device for sampling (default: cuda if available, else cpu)"
    )
    p.add_argument(
        "--dtype",
        choices=DTYPE_REQUESTS,
        default="auto",
        help="networks' precision, as for `relight` (default: auto: bfloat16 on a CPU with native "
        "bf16 for a model of 100M+ UNet parameters, else float32)",
    )
    p.add_argument("--threads", type=int, help="torch CPU threads (default: torch's)")
    p.add_argument(
        "--max-upload-mb", type=float, default=20.0, help="largest upload, per file (default 20)"
    )
    p.add_argument(
        "--max-image-side",
        type=int,
        default=4096,
        help="largest side of an uploaded photo or environment map, pixels (default 4096)",
    )
    p.add_argument(
        "--max-image-megapixels",
        type=float,
        default=16.8,
        help="largest photo or mask, millions of pixels (default 16.8, i.e. 4096x4096)",
    )
    p.add_argument(
        "--cache-max-age",
        type=int,
        default=3600,
        help="delete uploads and results older than this many seconds while serving (default 3600)",
    )
    p.add_argument(
        "--queue-size",
        type=int,
        default=16,
        help="jobs that may wait behind the running one (one job runs at a time; default 16)",
    )
    p.add_argument(
        "--max-frames", type=int, default=48, help="most turntable frames per request (default 48)"
    )
    p.add_argument(
        "--max-turntable-side",
        type=int,
        default=512,
        help="longest side of full-size turntable frames; larger photos are shrunk to it for the "
        "turntable only (default 512)",
    )


def _default_device() -> str:
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def config_from_args(args: argparse.Namespace) -> AppConfig:
    """Check the flags and the model folders (no model is loaded) and build the `AppConfig`.

    Raises:
        ConfigError: a bad value, a missing folder, or an authors' checkpoint without `--base-model`.
    """
    models = [ModelChoice(label=GAFFER_TINY_LABEL)]
    for path in args.model:
        path = Path(path).expanduser()
        if not path.is_dir():
            raise ConfigError(f"`--model` {path} is not a folder; pass a model folder.")
        if (path / MANIFEST_NAME).is_file():
            models.append(ModelChoice(label=path.name, checkpoint=path))
            continue
        if args.base_model is None:
            raise ConfigError(
                f"`--model` {path} is not a gaffer-diffusion model folder (no {MANIFEST_NAME}), so it is "
                "taken as the authors' release, which needs `--base-model DIR` (a local Zero-1-to-3 XL "
                "diffusers folder)."
            )
        if not Path(args.base_model).is_dir():
            raise ConfigError(f"`--base-model` {args.base_model} is not a folder.")
        models.append(
            ModelChoice(
                label=f"{path.name} (authors')", checkpoint=path, base_model=args.base_model
            )
        )
    return AppConfig(
        host=args.host,
        port=args.port,
        models=tuple(models),
        device=args.device or _default_device(),
        dtype=args.dtype,
        threads=args.threads,
        max_upload_mb=args.max_upload_mb,
        max_image_side=args.max_image_side,
        max_megapixels=args.max_image_megapixels,
        cache_max_age_s=args.cache_max_age,
        queue_size=args.queue_size,
        max_frames=args.max_frames,
        max_turntable_side=args.max_turntable_side,
    )
