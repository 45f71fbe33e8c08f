"""LPIPS-family networks re-stated without torchvision (which does not import beside our torch).

- `StLpipsAlex`: shift-tolerant LPIPS (Ghildyal & Liu, ECCV 2022), AlexNet variant "shift_tolerant"
  (stride-1 first conv, reflect-padded [1, 2, 1] blur-pool downsampling). Its weights (backbone AND linear
  heads) ship inside the `stlpips-pytorch` wheel; the module layout here reproduces the wheel's
  state-dict keys exactly so it loads with `strict=True`. Scores are NOT standard LPIPS.
- `LpipsAlex`: standard LPIPS v0.1 (Zhang et al., CVPR 2018) with the AlexNet backbone. The linear heads
  ship with torchmetrics; the ImageNet AlexNet backbone (torchvision's `alexnet-owt-7be5be79.pth`) is a
  download that cannot happen here, so it must be given as a local file.

Both take images in [-1, 1] and return `[B]` distances (spatially averaged, summed over 5 layers).
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn


class _ScalingLayer(nn.Module):
    shift: Tensor  # buffers, typed for nn.Module.__getattr__ (which says Tensor | Module)
    scale: Tensor

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        return (x - self.shift) / self.scale


class _BlurPool(nn.Module):
    """Reflect-pad by 2, then a stride-2 depthwise [1, 2, 1] x [1, 2, 1] / 16 blur (pad_more=True)."""

    filt: Tensor  # a buffer, typed for nn.Module.__getattr__ (which says Tensor | Module)

    def __init__(self, channels: int) -> None:
        super().__init__()
        a = torch.tensor([1.0, 2.0, 1.0])
        filt = (a[:, None] * a[None, :]) / 16.0
        self.register_buffer("filt", filt[None, None].repeat(channels, 1, 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        return F.conv2d(
            F.pad(x, (2, 2, 2, 2), mode="reflect"), self.filt, stride=2, groups=x.shape[1]
        )


class _NetLin(nn.Module):
    def __init__(self, channels: int) -> None:
        super().__init__()
        # index 0 was a Dropout in the original (identity in eval); keep index 1 for the weight key
        self.model = nn.Sequential(nn.Identity(), nn.Conv2d(channels, 1, 1, bias=False))

    def forward(self, x: Tensor) -> Tensor:
        return self.model(x)


def _seq(modules: dict[int, nn.Module]) -> nn.Sequential:
    seq = nn.Sequential()
    for i, m in modules.items():
        seq.add_module(str(i), m)
    return seq


class _Slices(nn.Module):
    def __init__(self, slices: list[nn.Sequential]) -> None:
        super().__init__()
        for i, s in enumerate(slices, start=1):
            self.add_module(f"slice{i}", s)

    def forward(self, x: Tensor) -> list[Tensor]:
        feats = []
        for i in range(1, 6):
            x = getattr(self, f"slice{i}")(x)
            feats.append(x)
        return feats


def _shift_tolerant_alexnet() -> _Slices:
    return _Slices(
        [
            _seq({0: nn.Conv2d(3, 64, 11, stride=1, padding=2), 1: _BlurPool(64), 2: nn.ReLU()}),
            _seq(
                {
                    3: nn.MaxPool2d(3, stride=1),
                    4: _BlurPool(64),
                    5: nn.Conv2d(64, 192, 5, padding=2),
                    6: nn.ReLU(),
                }
            ),
            _seq(
                {
                    7: nn.MaxPool2d(3, stride=1),
                    8: _BlurPool(192),
                    9: nn.Conv2d(192, 384, 3, padding=1),
                    10: nn.ReLU(),
                }
            ),
            _seq({11: nn.Conv2d(384, 256, 3, padding=1), 12: nn.ReLU()}),
            _seq({13: nn.Conv2d(256, 256, 3, padding=1), 14: nn.ReLU()}),
        ]
    )


def _torchvision_alexnet() -> _Slices:
    return _Slices(
        [
            _seq({0: nn.Conv2d(3, 64, 11, stride=4, padding=2), 1: nn.ReLU()}),
            _seq({2: nn.MaxPool2d(3, 2), 3: nn.Conv2d(64, 192, 5, padding=2), 4: nn.ReLU()}),
            _seq({5: nn.MaxPool2d(3, 2), 6: nn.Conv2d(192, 384, 3, padding=1), 7: nn.ReLU()}),
            _seq({8: nn.Conv2d(384, 256, 3, padding=1), 9: nn.ReLU()}),
            _seq({10: nn.Conv2d(256, 256, 3, padding=1), 11: nn.ReLU()}),
        ]
    )


_ALEX_CHANNELS = (64, 192, 384, 256, 256)


class _LpipsBase(nn.Module):
    def __init__(self, net: _Slices) -> None:
        super().__init__()
        self.scaling_layer = _ScalingLayer()
        self.net = net
        for i, c in enumerate(_ALEX_CHANNELS):
            self.add_module(f"lin{i}", _NetLin(c))
        self.requires_grad_(False)
        self.eval()

    def forward(self, in0: Tensor, in1: Tensor) -> Tensor:
        """`[B]` distances between `[B, 3, H, W]` images in [-1, 1]."""
        f0 = self.net(self.scaling_layer(in0))
        f1 = self.net(self.scaling_layer(in1))
        total = torch.zeros(in0.shape[0], device=in0.device, dtype=in0.dtype)
        for i, (a, b) in enumerate(zip(f0, f1, strict=True)):
            a = a / (torch.sqrt(torch.sum(a**2, dim=1, keepdim=True)) + 1e-10)
            b = b / (torch.sqrt(torch.sum(b**2, dim=1, keepdim=True)) + 1e-10)
            total = total + getattr(self, f"lin{i}")((a - b) ** 2).mean(dim=(1, 2, 3))
        return total


class StLpipsAlex(_LpipsBase):
    """Shift-tolerant LPIPS, AlexNet; load the wheel's `alex_shift_tolerant.pth` with strict=True."""

    def __init__(self) -> None:
        super().__init__(_shift_tolerant_alexnet())


class LpipsAlex(_LpipsBase):
    """Standard LPIPS v0.1, AlexNet (torchvision layout) + linear heads."""

    def __init__(self) -> None:
        super().__init__(_torchvision_alexnet())

    def load_backbone(self, torchvision_state: dict[str, Tensor]) -> None:
        """Load torchvision AlexNet weights (`features.N.weight` keys; the classifier is ignored)."""
        mapped = {}
        for slice_idx, layers in enumerate(((0,), (3,), (6,), (8,), (10,)), start=1):
            for layer in layers:
                for p in ("weight", "bias"):
                    mapped[f"slice{slice_idx}.{layer}.{p}"] = torchvision_state[
                        f"features.{layer}.{p}"
                    ]
        self.net.load_state_dict(mapped, strict=True)

    def load_heads(self, heads_state: dict[str, Tensor]) -> None:
        """Load the LPIPS v0.1 linear heads (`lin{i}.model.1.weight` keys)."""
        lins = {k: v for k, v in heads_state.items() if k.startswith("lin")}
        missing = [
            f"lin{i}.model.1.weight" for i in range(5) if f"lin{i}.model.1.weight" not in lins
        ]
        if missing:
            raise KeyError(f"LPIPS head weights lack {missing}")
        for k, v in lins.items():
            i = int(k[3])
            getattr(self, f"lin{i}").model[1].weight.data.copy_(v)
