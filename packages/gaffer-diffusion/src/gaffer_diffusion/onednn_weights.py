"""Convolution and linear weights kept in oneDNN's own layout on the bf16 CPU path.

An eager `nn.Conv2d` / `nn.Linear` hands oneDNN its weight in PyTorch's layout at every call, and
oneDNN reorders it into the blocked layout its AMX / AVX512-BF16 kernels read, every sampling step:
for the paper's 860M-parameter UNet that is the whole model rewritten once per step.
`prepack_onednn_weights` has each layer reorder its weight once (on its first bf16 call without
gradients) and then call oneDNN's kernels on the packed copy (`torch.ops.mkldnn._convolution_pointwise`
and `_linear_pointwise`, the ops `torch.compile`'s CPU "freezing" emits, here without compiling).
The eager layers call oneDNN too, so the arithmetic is the same up to the kernels oneDNN picks for
each layout: on the small test UNet (`testing.tiny_model`) the outputs are equal bit for bit (on
this project's AMX CPU), on the paper's one UNet step
differs by at most 0.018 (bf16 rounding), and the decoded images of a full sample stay as close to
float32's as without packing (`benchmarks/results/cpu_fast.json`, which also has the time saved).

A layer uses its packed copy only while it still describes the weight: the same storage, version
(an in-place update bumps it), dtype and device; under autograd (a weight or input that requires
grad, with grad enabled), for float32 weights and for `padding_mode`s other than zeros it runs the
eager layer. Deep copies and `.float()` copies therefore stay correct; they pack again if they
qualify. The packed copies cost the weights' size again in memory (1.7 GB for the paper's UNet).
"""

import weakref
from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor, nn


@dataclass(frozen=True)
class _Packed:
    """A layer's weight in oneDNN's layout and the weight it was made from."""

    weight: Tensor
    source_ptr: int
    source_version: int
    dtype: torch.dtype


_PACKED: "weakref.WeakKeyDictionary[nn.Module, _Packed]" = weakref.WeakKeyDictionary()


def _usable(layer: nn.Conv2d | nn.Linear, x: Tensor) -> bool:
    w = layer.weight
    if w.dtype != torch.bfloat16 or x.dtype != torch.bfloat16 or w.device.type != "cpu":
        return False
    if x.device.type != "cpu" or x.is_mkldnn:
        return False
    return not (torch.is_grad_enabled() and (x.requires_grad or w.requires_grad))


def _packed(layer: nn.Module, make: Any) -> Tensor:
    """The layer's packed weight, made now if it has none or its weight changed since."""
    w: Tensor = layer.weight  # type: ignore[assignment]
    cached = _PACKED.get(layer)
    version = w._version  # bumped by every in-place update (load_state_dict, copy_, optimizer)
    if (
        cached is None
        or cached.source_ptr != w.data_ptr()
        or cached.source_version != version
        or cached.dtype != w.dtype
    ):
        cached = _Packed(
            weight=make(w.detach()), source_ptr=w.data_ptr(), source_version=version, dtype=w.dtype
        )
        _PACKED[layer] = cached
    return cached.weight


class _PackedConv2d(nn.Conv2d):
    """`nn.Conv2d` that calls oneDNN with its weight packed once (see the module docstring)."""

    def forward(self, input: Tensor) -> Tensor:
        if (
            self.padding_mode != "zeros"
            or isinstance(self.padding, str)
            or input.dim() != 4
            or not _usable(self, input)
        ):
            return super().forward(input)
        padding = list(self.padding)
        stride, dilation = list(self.stride), list(self.dilation)
        weight = _packed(
            self,
            lambda w: torch.ops.mkldnn._reorder_convolution_weight(
                w, padding, stride, dilation, self.groups, list(input.shape)
            ),
        )
        return torch.ops.mkldnn._convolution_pointwise(
            input, weight, self.bias, padding, stride, dilation, self.groups, "none", [], ""
        )


class _PackedLinear(nn.Linear):
    """`nn.Linear` that calls oneDNN with its weight packed once (see the module docstring)."""

    def forward(self, input: Tensor) -> Tensor:
        if not _usable(self, input) or input.dim() < 2:
            return super().forward(input)
        rows = input.numel() // max(input.shape[-1], 1)
        weight = _packed(self, lambda w: torch.ops.mkldnn._reorder_linear_weight(w, rows))
        return torch.ops.mkldnn._linear_pointwise(input, weight, self.bias, "none", [], "")


def prepack_onednn_weights(module: nn.Module) -> int:
    """Have every plain `nn.Conv2d` and `nn.Linear` in `module` keep its weight packed for oneDNN.

    In place (the layers change class to a subclass with the same parameters, state dict and
    `isinstance`); packing happens on each layer's first qualifying call. Returns the number of
    layers changed. `unpack_onednn_weights` undoes it.

    Example:
        >>> net = nn.Sequential(nn.Conv2d(4, 8, 3), nn.Flatten(), nn.Linear(8, 2))
        >>> prepack_onednn_weights(net)
        2
    """
    changed = 0
    for layer in module.modules():
        if type(layer) is nn.Conv2d:
            layer.__class__ = _PackedConv2d
            changed += 1
        elif type(layer) is nn.Linear:
            layer.__class__ = _PackedLinear
            changed += 1
    return changed


def unpack_onednn_weights(module: nn.Module) -> int:
    """Undo `prepack_onednn_weights`: the layers become plain again and drop their packed copies."""
    changed = 0
    for layer in module.modules():
        swap: Any = layer  # a class change the type checker cannot follow
        if type(layer) is _PackedConv2d:
            swap.__class__ = nn.Conv2d
        elif type(layer) is _PackedLinear:
            swap.__class__ = nn.Linear
        else:
            continue
        _PACKED.pop(layer, None)
        changed += 1
    return changed


def packed_layers(module: nn.Module) -> int:
    """How many of `module`'s layers hold a packed weight now (after their first call)."""
    return sum(1 for layer in module.modules() if layer in _PACKED)


__all__ = ["packed_layers", "prepack_onednn_weights", "unpack_onednn_weights"]
