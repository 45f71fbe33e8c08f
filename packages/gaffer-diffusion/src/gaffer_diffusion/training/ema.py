"""Exponential moving average of the UNet weights (kept for validation, saved in every checkpoint).

The authors kept an EMA but never checkpointed it (official implementation §8); ours is saved as
`ema_unet.safetensors` beside the training state and is what `final/` holds.
"""

from collections.abc import Iterable

import torch
from safetensors.torch import load_file, save_file
from torch import nn


class EMAModel:
    """theta_ema <- d theta_ema + (1 - d) theta, with the warm-up d = min(decay, (1 + n) / (10 + n)).

    Shadow weights are float32 on the parameters' device, keyed by parameter name.

    Args:
        module: the trained module (its `named_parameters()` that require grad are tracked).
        decay: the target decay (0.9999 for long runs).

    Example:
        >>> lin = torch.nn.Linear(2, 2)
        >>> ema = EMAModel(lin, decay=0.9)
        >>> ema.update(lin)
        >>> ema.num_updates
        1
    """

    def __init__(self, module: nn.Module, decay: float) -> None:
        self.decay = float(decay)
        self.num_updates = 0
        self.shadow: dict[str, torch.Tensor] = {
            name: p.detach().float().clone()
            for name, p in module.named_parameters()
            if p.requires_grad
        }

    def current_decay(self) -> float:
        """The decay the next `update` applies."""
        n = self.num_updates
        return min(self.decay, (1.0 + n) / (10.0 + n))

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        """Blend `module`'s current parameters into the shadow weights."""
        d = self.current_decay()
        for name, p in _named(module):
            s = self.shadow.get(name)
            if s is not None:
                s.mul_(d).add_(p.detach().float(), alpha=1.0 - d)
        self.num_updates += 1

    @torch.no_grad()
    def copy_to(self, module: nn.Module) -> None:
        """Write the shadow weights into `module` (cast to each parameter's dtype)."""
        for name, p in _named(module):
            s = self.shadow.get(name)
            if s is not None:
                p.copy_(s.to(device=p.device, dtype=p.dtype))

    def save(self, path: str) -> None:
        """Write the shadow weights and `num_updates` / `decay` as safetensors."""
        meta = {"num_updates": str(self.num_updates), "decay": repr(self.decay)}
        save_file({k: v.detach().cpu().contiguous() for k, v in self.shadow.items()}, path, meta)

    def load(self, path: str) -> None:
        """Read weights written by `save` (onto the shadow tensors' devices).

        Raises:
            KeyError: the file lacks a tracked parameter.
        """
        from safetensors import safe_open

        state = load_file(path)
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
        missing = sorted(set(self.shadow) - set(state))
        if missing:
            raise KeyError(f"EMA file {path} lacks {len(missing)} parameters, e.g. {missing[:3]}")
        for k, s in self.shadow.items():
            s.copy_(state[k].to(s.device))
        self.num_updates = int(meta.get("num_updates", "0"))


def _named(module: nn.Module) -> Iterable[tuple[str, torch.Tensor]]:
    return ((n, p) for n, p in module.named_parameters() if p.requires_grad)
