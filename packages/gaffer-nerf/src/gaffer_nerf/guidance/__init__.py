"""The 2D relighting model as a 3D prior: relit views, guidance targets from t*, SDS, perceptual loss."""

from gaffer_nerf.guidance.diffusion import DiffusionGuide, ViewConditions, t_star
from gaffer_nerf.guidance.model import RelightingModel, load_relighting_model, smoke_model
from gaffer_nerf.guidance.perceptual import (
    PerceptualLoss,
    PerceptualUnavailableWarning,
    load_perceptual_loss,
    unavailable_perceptual,
)

__all__ = [
    "DiffusionGuide",
    "PerceptualLoss",
    "PerceptualUnavailableWarning",
    "RelightingModel",
    "ViewConditions",
    "load_perceptual_loss",
    "load_relighting_model",
    "smoke_model",
    "t_star",
    "unavailable_perceptual",
]
