"""Frozen configs of the runtime (`RuntimeConfig`) and of a sampling call (`SamplingConfig`).

`SamplingConfig` lives in the torch-free `gaffer_diffusion.sampling_config` (the command line builds it
before torch loads) and is re-exported here, where it always was.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, assert_never

import torch

from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.sampling_config import NonFinitePolicy as NonFinitePolicy
from gaffer_diffusion.sampling_config import SamplingConfig as SamplingConfig

AttentionBackend = Literal["sdpa", "eager"]
"""Attention kernels: PyTorch `scaled_dot_product_attention` (diffusers' default) or plain matmuls."""

DtypeName = Literal["float32", "float16", "bfloat16"]

if TYPE_CHECKING:
    from gaffer_diffusion.runtime_dtype import DtypeRequest

    _DtypeArg = DtypeRequest
else:  # at run time any str reaches `RuntimeConfig`, which refuses an unknown one
    _DtypeArg = str


@dataclass(frozen=True, kw_only=True)
class RuntimeConfig:
    """Where and how the networks run.

    Attributes:
        device: torch device string ("cpu", "cuda", "cuda:1").
        dtype: "float32", "float16" or "bfloat16" for all networks, or "auto": bfloat16 on a CPU
            with native bf16 for a large UNet, else float32 (`gaffer_diffusion.runtime_dtype`;
            `RelightPipeline` resolves it and keeps the resolved config as its `runtime`).
        attention: "sdpa" (default) or "eager".
        compile: wrap the UNet in `torch.compile` (first call is slow; worth it for many calls).
        compile_mode: `torch.compile` mode, e.g. "max-autotune"; None for the default.
        compile_backend: `torch.compile` backend ("inductor"; "eager" only checks the wiring).
        autocast: keep the networks in float32 and run the UNet under `torch.autocast` in `dtype`
            (float16 or bfloat16) instead of casting the weights: the authors' fp16 inference (our
            reading of their inference script). The encoders and the VAE decoder stay float32
            (our reading: they name fp16 autocast for the UNet only). CLI: `--dtype float16` on CUDA with `--compat
            neural-gaffer`.
    """

    device: str = "cpu"
    dtype: _DtypeArg = "float32"
    attention: AttentionBackend = "sdpa"
    compile: bool = False
    compile_mode: str | None = None
    compile_backend: str = "inductor"
    autocast: bool = False

    def __post_init__(self) -> None:
        if self.dtype not in ("auto", "float32", "float16", "bfloat16"):
            raise ConfigError(
                f"`dtype` is {self.dtype!r}; expected 'auto', 'float32', 'float16' or 'bfloat16'."
            )
        if self.autocast and self.dtype == "auto":
            raise ConfigError(
                "`autocast` is on with `dtype` 'auto'; autocast needs the lower precision named: "
                "pass dtype 'float16' (the authors') or 'bfloat16'."
            )
        if self.attention not in ("sdpa", "eager"):
            raise ConfigError(f"`attention` is {self.attention!r}; expected 'sdpa' or 'eager'.")
        try:
            torch.device(self.device)
        except (RuntimeError, TypeError) as exc:
            raise ConfigError(f"`device` is {self.device!r}, not a torch device.") from exc
        if self.autocast and self.dtype == "float32":
            raise ConfigError(
                "`autocast` is on with `dtype` 'float32'; autocast runs the UNet in a lower "
                "precision: pass dtype 'float16' (the authors') or 'bfloat16'."
            )

    @property
    def weights_dtype(self) -> torch.dtype:
        """The dtype the weights (and the tensors between networks) are kept in: float32 under
        `autocast`, else `torch_dtype`."""
        return torch.float32 if self.autocast else self.torch_dtype

    @property
    def torch_dtype(self) -> torch.dtype:
        """The torch dtype named by `dtype`."""
        match self.dtype:
            case "float32":
                return torch.float32
            case "float16":
                return torch.float16
            case "bfloat16":
                return torch.bfloat16
            case "auto":
                raise ConfigError(
                    "`dtype` 'auto' names no torch dtype until it is resolved: use "
                    "`RelightPipeline(model, runtime).runtime` or `runtime_dtype.resolve_dtype`."
                )
            case _:
                assert_never(self.dtype)
