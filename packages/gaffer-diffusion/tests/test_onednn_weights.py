"""The bf16 CPU path keeps conv/linear weights in oneDNN's layout: the eager layers' outputs (up to
the kernels oneDNN picks: bf16 rounding), repacked when a weight changes, eager under autograd and for
float32 copies. A wrong padding, stride, group count or stale weight would be off by far more."""

import copy

import pytest
import torch

from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig
from gaffer_diffusion.onednn_weights import (
    packed_layers,
    prepack_onednn_weights,
    unpack_onednn_weights,
)
from gaffer_diffusion.runtime_dtype import detect_cpu_bf16
from gaffer_diffusion.testing import random_conditions, tiny_model

native = pytest.mark.skipif(
    not detect_cpu_bf16().native,
    reason="oneDNN's packed bf16 kernels need native bf16 (AMX/AVX512)",
)


def _close(a: torch.Tensor, b: torch.Tensor) -> None:
    """Equal up to bf16 rounding (bit for bit on this project's AMX CPU)."""
    torch.testing.assert_close(a.float(), b.float(), atol=2e-2, rtol=2e-2)


def _net() -> torch.nn.Module:
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Conv2d(8, 16, 3, padding=1),
        torch.nn.SiLU(),
        torch.nn.Conv2d(16, 16, 3, stride=2, padding=1, groups=2),
        torch.nn.Flatten(),
        torch.nn.Linear(16 * 4 * 4, 10),
    )
    return net.to(torch.bfloat16).to(memory_format=torch.channels_last).eval()


@native
def test_packed_layers_give_the_eager_outputs_bit_for_bit() -> None:
    net = _net()
    eager = copy.deepcopy(net)
    x = torch.randn(3, 8, 8, 8, dtype=torch.bfloat16).contiguous(memory_format=torch.channels_last)
    assert prepack_onednn_weights(net) == 3
    with torch.no_grad():
        _close(net(x), eager(x))
        assert packed_layers(net) == 3
        _close(net(x[:1]), eager(x[:1]))  # another batch size, same packed weights
        # an in-place weight update (load_state_dict, an optimizer) is seen: packed again
        net[0].weight.add_(0.5)
        eager[0].weight.add_(0.5)
        _close(net(x), eager(x))
    # under autograd the eager layers run (the packed ops have no backward)
    xg = x.clone().requires_grad_(True)
    net(xg).float().sum().backward()
    assert xg.grad is not None and bool(torch.isfinite(xg.grad).all())
    # a float32 copy runs eagerly in float32
    f32 = copy.deepcopy(net).float()
    with torch.no_grad():
        out = f32(x.float())
    assert out.dtype == torch.float32
    assert unpack_onednn_weights(net) == 3 and packed_layers(net) == 0
    assert type(net[0]) is torch.nn.Conv2d


@native
def test_bf16_pipeline_packs_and_samples_as_without() -> None:
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype="bfloat16"))
    cond = random_conditions(2, pipe.model.config.resolution, seed=3)
    sampling = SamplingConfig(num_inference_steps=3, guidance_scale=3.0, scheduler="dpmpp-2m")
    packed = pipe(cond, sampling, seeds=[0, 1]).images
    assert packed_layers(pipe.model.unet) > 0
    assert unpack_onednn_weights(pipe.model.vae) == 0  # the UNet only: it runs at every step
    unpack_onednn_weights(pipe.model.unet)
    _close(pipe(cond, sampling, seeds=[0, 1]).images, packed)


def test_float32_pipeline_is_not_packed() -> None:
    pipe = RelightPipeline(tiny_model(), RuntimeConfig(dtype="float32"))
    assert not any(type(m).__name__.startswith("_Packed") for m in pipe.model.unet.modules())
