"""The Neural Gaffer networks: a container and random-init builders (weights: `gaffer_diffusion.loading`)."""

from gaffer_diffusion.models.build import (
    build_image_encoder,
    build_model,
    build_scheduler,
    build_unet,
    build_vae,
    config_from_modules,
)
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.models.pixel import PixelAutoencoder
from gaffer_diffusion.models.surgery import expand_conv_in

__all__ = [
    "NeuralGafferModel",
    "PixelAutoencoder",
    "build_image_encoder",
    "build_model",
    "build_scheduler",
    "build_unet",
    "build_vae",
    "config_from_modules",
    "expand_conv_in",
]
