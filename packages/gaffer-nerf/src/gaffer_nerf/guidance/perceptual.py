"""The perceptual term of the Stage-2 loss, loaded offline and always labelled.

The authors use LPIPS (VGG). Here the perceptual network is whatever `gaffer_diffusion.metrics.
load_perceptual` provides offline: standard LPIPS (AlexNet) with a local backbone file, otherwise
shift-tolerant LPIPS (AlexNet) from the stlpips-pytorch wheel. When neither loads, the term is dropped
(weight 0), a warning says why, and every report carries the reason.
"""

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.errors import MetricUnavailableError
from gaffer_diffusion.metrics import load_perceptual


class PerceptualUnavailableWarning(UserWarning):
    """No perceptual network could be loaded; the perceptual loss term is dropped."""


@dataclass(frozen=True, kw_only=True)
class PerceptualLoss:
    """A differentiable perceptual distance, or none, with its label.

    Attributes:
        name: "lpips-alex", "stlpips-alex", or None when unavailable.
        unavailable_reason: why there is none (None when there is one).
    """

    name: str | None
    unavailable_reason: str | None = None
    network: torch.nn.Module | None = field(default=None, repr=False, compare=False)

    @property
    def available(self) -> bool:
        """Whether the term can be computed."""
        return self.network is not None

    def __call__(
        self, pred: Float[Tensor, "B 3 H W"], target: Float[Tensor, "B 3 H W"]
    ) -> Float[Tensor, ""]:
        """Mean distance between images in [0, 1] (0 when unavailable), differentiable in `pred`."""
        if self.network is None:
            return pred.new_zeros(())
        p = next(self.network.parameters())
        a = (pred * 2 - 1).to(device=p.device, dtype=p.dtype)
        b = (target * 2 - 1).to(device=p.device, dtype=p.dtype)
        return self.network(a, b).float().mean().to(pred.device)


def load_perceptual_loss(
    lpips_backbone: str | Path | None = None, *, device: str | torch.device = "cpu"
) -> PerceptualLoss:
    """Load the perceptual network offline; on failure warn and return an unavailable, labelled one."""
    try:
        metric = load_perceptual(lpips_backbone)
    except MetricUnavailableError as exc:
        warnings.warn(
            f"No perceptual network for the Stage-2 loss ({exc}); using the L1 term only. Install "
            '"gaffer-diffusion[metrics]" (ships shift-tolerant LPIPS weights) to restore it.',
            PerceptualUnavailableWarning,
            stacklevel=2,
        )
        return PerceptualLoss(name=None, unavailable_reason=str(exc))
    net = metric.network.to(device).eval()
    net.requires_grad_(False)
    return PerceptualLoss(name=metric.name, network=net)


def unavailable_perceptual(reason: str) -> PerceptualLoss:
    """A perceptual term that is off, labelled with `reason` (e.g. "not requested")."""
    return PerceptualLoss(name=None, unavailable_reason=reason)
