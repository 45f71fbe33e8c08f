"""Precision and memory layout of inference: `--dtype auto` and the fast CPU path.

The authors run their UNet under fp16 autocast with xformers on a GPU (official implementation §2)
and have no CPU path; in float32 on a 2-core CPU the paper-size model takes about 3 minutes per image
(`benchmarks/results/diffusion_speed.json`). On a CPU with native bfloat16 (Intel AMX-BF16 or
AVX512-BF16) oneDNN runs bf16 convolutions and matmuls in hardware, and bf16 weights with
channels-last convolutions cut a step about 3x (`benchmarks/results/cpu_fast.json`). A CPU without
them (AVX2 only) emulates bf16 and is slower than in float32, so `auto` keeps float32 there.

`resolve_dtype("auto", device)` names the dtype and why; `prepare_for_inference` puts the networks'
attention on PyTorch's `scaled_dot_product_attention` and, on the bf16 CPU path, their convolutions in
channels-last layout. Torch-free at import (the CLI resolves `--dtype` before torch loads); `/proc/cpuinfo`
and the oneDNN environment are read only when asked.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, TypeVar, get_args, runtime_checkable

if TYPE_CHECKING:
    import torch

    from gaffer_diffusion.models.model import NeuralGafferModel


@runtime_checkable
class RuntimeConfig(Protocol):
    """What this module reads of `gaffer_diffusion.pipelines.RuntimeConfig` (a protocol, so that the
    pipelines, which import this module, are not imported back)."""

    @property
    def device(self) -> str: ...
    @property
    def dtype(self) -> Any: ...
    @property
    def attention(self) -> str: ...
    @property
    def autocast(self) -> bool: ...
    @property
    def compile(self) -> bool: ...


_Runtime = TypeVar("_Runtime", bound=RuntimeConfig)

DtypeRequest = Literal["auto", "float32", "float16", "bfloat16"]
"""What `--dtype` accepts: `auto` resolves to one of the other three (`resolve_dtype`)."""

DTYPE_REQUESTS: tuple[DtypeRequest, ...] = get_args(DtypeRequest)

ResolvedDtype = Literal["float32", "float16", "bfloat16"]

BF16_CPU_FLAGS: tuple[str, ...] = ("amx_bf16", "avx512_bf16")
"""`/proc/cpuinfo` flags of native bf16 arithmetic on x86: AMX tiles (Sapphire Rapids and later) and
AVX512-BF16 dot products (Cooper Lake, Zen 4 and later). oneDNN's bf16 kernels need one of them."""

AUTO_BF16_MIN_UNET_PARAMS = 100_000_000
"""`auto` picks bf16 for a UNet of at least this many parameters (the paper's: 860M). Smaller models
(gaffer-tiny: 3.8M) stay float32 under `auto`: a sample takes well under a second either way, their
shipped scores and the library's default (`RuntimeConfig`) are float32, and the CLI then writes the
same pixels as the library and the app. `--dtype bfloat16` runs them in bf16 too."""

_ONEDNN_ISA_VARS = ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA")
_BF16_ISA_MARKERS = ("BF16", "AMX", "FP16", "AVX10", "ALL")
"""`ONEDNN_MAX_CPU_ISA` values that still allow oneDNN's native bf16 kernels (e.g. AVX512_CORE_BF16,
AVX512_CORE_AMX, ALL); AVX2, AVX2_VNNI, AVX512_CORE and AVX512_CORE_VNNI do not."""


@dataclass(frozen=True, kw_only=True)
class CpuBf16Support:
    """Whether this CPU (as torch's oneDNN may use it) has native bf16 arithmetic.

    Attributes:
        flags: the native-bf16 flags the CPU lists (subset of `BF16_CPU_FLAGS`).
        capability: `torch.backends.cpu.get_cpu_capability()` ("AVX512", "AVX2", "DEFAULT", ...), or
            "" when not asked.
        isa_limit: `ONEDNN_MAX_CPU_ISA` (or `DNNL_MAX_CPU_ISA`) when set, else None.
    """

    flags: tuple[str, ...]
    capability: str = ""
    isa_limit: str | None = None

    @property
    def isa_allows_bf16(self) -> bool:
        """False when `ONEDNN_MAX_CPU_ISA` keeps oneDNN below its bf16 instruction sets."""
        if self.isa_limit is None:
            return True
        limit = self.isa_limit.upper()
        return any(marker in limit for marker in _BF16_ISA_MARKERS)

    @property
    def native(self) -> bool:
        """The CPU has a bf16 flag, torch dispatches AVX512 kernels here (or was not asked) and the
        oneDNN ISA limit allows bf16."""
        avx512 = self.capability == "" or self.capability.upper().startswith("AVX512")
        return bool(self.flags) and avx512 and self.isa_allows_bf16

    def describe(self) -> str:
        """Why `native` is what it is, in a few words (for the CLI's output line)."""
        if not self.flags:
            return "the CPU has no native bf16 (no AMX-BF16 / AVX512-BF16)"
        names = "/".join(_FLAG_NAMES[f] for f in self.flags)
        if not self.isa_allows_bf16:
            return (
                f"the CPU has {names} but ONEDNN_MAX_CPU_ISA={self.isa_limit} keeps oneDNN off it"
            )
        if not self.native:
            return f"the CPU has {names} but torch runs {self.capability} kernels here"
        return f"the CPU has {names}"


_FLAG_NAMES = {"amx_bf16": "AMX-BF16", "avx512_bf16": "AVX512-BF16"}


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> frozenset[str]:
    """The CPU feature flags of the first processor in `/proc/cpuinfo` (empty where there is none,
    e.g. macOS or Windows: those CPUs are then taken to have no native bf16)."""
    try:
        text = cpuinfo.read_text(errors="replace")
    except OSError:
        return frozenset()
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() in ("flags", "Features"):
            return frozenset(value.split())
    return frozenset()


def detect_cpu_bf16(
    *,
    flags: frozenset[str] | None = None,
    capability: str | None = None,
    environ: dict[str, str] | None = None,
) -> CpuBf16Support:
    """Native bf16 support of this CPU: `/proc/cpuinfo` flags, torch's CPU capability, oneDNN's limit.

    Args:
        flags: the CPU flags (default: read from `/proc/cpuinfo`).
        capability: torch's dispatch level (default: `torch.backends.cpu.get_cpu_capability()`).
        environ: the environment to read `ONEDNN_MAX_CPU_ISA` from (default: `os.environ`).

    Example:
        >>> detect_cpu_bf16(flags=frozenset({"avx2"}), capability="AVX2", environ={}).native
        False
        >>> s = detect_cpu_bf16(flags=frozenset({"amx_bf16"}), capability="AVX512", environ={})
        >>> s.native, s.describe()
        (True, 'the CPU has AMX-BF16')
    """
    if flags is None:
        flags = cpu_flags()
    if capability is None:
        import torch

        capability = str(torch.backends.cpu.get_cpu_capability())
    env = os.environ if environ is None else environ
    limit = next((env[v] for v in _ONEDNN_ISA_VARS if env.get(v)), None)
    return CpuBf16Support(
        flags=tuple(f for f in BF16_CPU_FLAGS if f in flags), capability=capability, isa_limit=limit
    )


@dataclass(frozen=True, kw_only=True)
class DtypeChoice:
    """The dtype a run uses and why.

    Attributes:
        requested: what was asked (`--dtype`).
        dtype: what runs.
        reason: why, in words (shown in the CLI's output line).
    """

    requested: DtypeRequest
    dtype: ResolvedDtype
    reason: str

    def note(self) -> str:
        """`precision: bfloat16 (auto: the CPU has AMX-BF16/AVX512-BF16)`."""
        return f"precision: {self.dtype} ({self.reason})"


def resolve_dtype(
    requested: DtypeRequest,
    device: str,
    *,
    unet_params: int | None = None,
    support: CpuBf16Support | None = None,
) -> DtypeChoice:
    """The dtype of `--dtype requested` on `device`.

    `auto` on a CPU: bfloat16 where the CPU has native bf16 and the UNet has at least
    `AUTO_BF16_MIN_UNET_PARAMS` parameters (unknown size counts as large), float32 elsewhere. `auto` on
    a GPU or MPS: float32, today's default (the GPU fast path is not measured here). An explicit dtype
    is kept; bfloat16 on a CPU without native bf16 is kept too, with the warning in its reason.

    Args:
        requested: "auto", "float32", "float16" or "bfloat16".
        device: the torch device string ("cpu", "cuda:0", ...).
        unet_params: the UNet's parameter count, when known.
        support: the CPU's bf16 support (default: `detect_cpu_bf16()`, read only for CPU devices).

    Example:
        >>> amx = CpuBf16Support(flags=("amx_bf16",), capability="AVX512")
        >>> resolve_dtype("auto", "cpu", unet_params=860_000_000, support=amx).dtype
        'bfloat16'
        >>> resolve_dtype("auto", "cpu", support=CpuBf16Support(flags=())).dtype
        'float32'
    """
    if requested not in DTYPE_REQUESTS:
        from gaffer_diffusion.errors import ConfigError

        raise ConfigError(
            f"`--dtype` is {requested!r}; expected one of {', '.join(DTYPE_REQUESTS)} (auto: "
            "bfloat16 on a CPU with native bf16, else float32)."
        )
    on_cpu = device.split(":", 1)[0] == "cpu"
    if requested != "auto":
        if requested == "bfloat16" and on_cpu:
            cpu = support or detect_cpu_bf16()
            if not cpu.native:
                return DtypeChoice(
                    requested=requested,
                    dtype=requested,
                    reason=f"--dtype bfloat16; slow here: {cpu.describe()}, bf16 is emulated",
                )
        return DtypeChoice(requested=requested, dtype=requested, reason=f"--dtype {requested}")
    if not on_cpu:
        return DtypeChoice(
            requested=requested, dtype="float32", reason=f"auto: float32 on {device}"
        )
    cpu = support or detect_cpu_bf16()
    if not cpu.native:
        return DtypeChoice(requested=requested, dtype="float32", reason=f"auto: {cpu.describe()}")
    if unet_params is not None and unet_params < AUTO_BF16_MIN_UNET_PARAMS:
        return DtypeChoice(
            requested=requested,
            dtype="float32",
            reason=f"auto: a small model ({unet_params / 1e6:.1f}M UNet parameters) stays float32; "
            "--dtype bfloat16 for bf16",
        )
    return DtypeChoice(requested=requested, dtype="bfloat16", reason=f"auto: {cpu.describe()}")


def unet_parameter_count(model: NeuralGafferModel) -> int:
    """Parameters of the model's UNet (what `auto` weighs)."""
    return sum(p.numel() for p in model.unet.parameters())


def uses_channels_last(runtime: RuntimeConfig) -> bool:
    """Convolutions in channels-last layout on the bf16 CPU path: oneDNN's bf16 convolutions run
    without reorders in NHWC (measured 1.4x on gaffer-tiny's UNet, 1.15x on the paper's:
    `benchmarks/results/cpu_fast.json`). float32 runs keep PyTorch's default layout, so their pixels
    do not change."""
    on_cpu = runtime.device.split(":", 1)[0] == "cpu"
    return on_cpu and runtime.dtype == "bfloat16" and not runtime.autocast


def prepare_for_inference(model: NeuralGafferModel, runtime: RuntimeConfig) -> None:
    """Attention kernels and memory layout of every network, in place (after the dtype cast).

    - UNet and VAE attention through `scaled_dot_product_attention` (diffusers' `AttnProcessor2_0`),
      or plain matmuls with `runtime.attention == "eager"`; the CLIP tower likewise through
      transformers' `sdpa` / `eager` implementation.
    - On the bf16 CPU path (`uses_channels_last`), the UNet's and VAE's weights in channels-last
      layout; their activations follow the weights. Unless it is compiled (inductor packs its own),
      the UNet's convolution and linear weights are also kept in oneDNN's layout, reordered once
      instead of at every step (`gaffer_diffusion.onednn_weights`; agreement with float32 as
      without it). Not the VAE: it runs once per image, so packing would save nothing.
    """
    import torch
    from diffusers.models.attention_processor import AttnProcessor, AttnProcessor2_0

    for net in (model.unet, model.vae):
        setter = getattr(net, "set_attn_processor", None)  # the pixel-space VAE has no attention
        if setter is not None:
            setter(AttnProcessor2_0() if runtime.attention == "sdpa" else AttnProcessor())
    encoder_setter = getattr(model.image_encoder, "set_attn_implementation", None)
    if encoder_setter is not None:
        encoder_setter(runtime.attention)
    if uses_channels_last(runtime):
        for net in (model.unet, model.vae):
            # plain nn.Module.to (diffusers' override logs a line about keep-in-fp32 modules); its
            # typed overloads omit the `memory_format` keyword it takes
            module_to: Any = torch.nn.Module.to
            module_to(net, memory_format=torch.channels_last)
        # oneDNN's packed bf16 kernels need the native bf16 ISA (`--dtype bfloat16` on an AVX2-only
        # CPU runs torch's own emulated kernels instead)
        if not runtime.compile and detect_cpu_bf16().native:
            from gaffer_diffusion.onednn_weights import prepack_onednn_weights

            prepack_onednn_weights(model.unet)


def torch_dtype_of(name: ResolvedDtype) -> torch.dtype:
    """The torch dtype of a resolved dtype name."""
    import torch

    return {"float32": torch.float32, "float16": torch.float16, "bfloat16": torch.bfloat16}[name]


__all__ = [
    "AUTO_BF16_MIN_UNET_PARAMS",
    "BF16_CPU_FLAGS",
    "DTYPE_REQUESTS",
    "CpuBf16Support",
    "DtypeChoice",
    "DtypeRequest",
    "cpu_flags",
    "detect_cpu_bf16",
    "prepare_for_inference",
    "resolve_dtype",
    "unet_parameter_count",
    "uses_channels_last",
]


def resolve_runtime(model: NeuralGafferModel, runtime: _Runtime) -> tuple[_Runtime, DtypeChoice]:
    """`runtime` with its dtype resolved for `model` (`resolve_dtype`, `auto` weighing the UNet's
    size), and the choice with its reason."""
    import dataclasses

    size = unet_parameter_count(model) if runtime.dtype == "auto" else None
    choice = resolve_dtype(runtime.dtype, runtime.device, unet_params=size)
    resolved: Any = dataclasses.replace(runtime, dtype=choice.dtype)  # type: ignore[type-var]
    return resolved, choice
