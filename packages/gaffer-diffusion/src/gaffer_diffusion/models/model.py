"""`NeuralGafferModel`: the four parts of the relighting model, held together with their config."""

from dataclasses import dataclass
from typing import cast

import torch
from diffusers.models.autoencoders.autoencoder_kl import AutoencoderKL
from diffusers.models.autoencoders.vae import DecoderOutput, DiagonalGaussianDistribution
from diffusers.models.unets.unet_2d_condition import UNet2DConditionModel
from jaxtyping import Float
from torch import Tensor
from transformers import CLIPVisionModelWithProjection

from gaffer_diffusion.configs import ModelConfig
from gaffer_diffusion.images import linear_to_srgb, srgb_to_linear
from gaffer_diffusion.models.pixel import PixelAutoencoder, PixelPosterior


@dataclass(frozen=True, kw_only=True)
class NeuralGafferModel:
    """The networks of Neural Gaffer (paper §3.2): encoder E, denoiser eps_theta, decoder D, CLIP c(x).

    The dataclass is frozen (the references do not change); the modules inside are ordinary
    `torch.nn.Module`s, moved with `to()`.

    Attributes:
        config: the shapes these modules were built with (for loaded weights: read from their configs).
        unet: the 16-input-channel denoiser.
        vae: the SD autoencoder (frozen in training), or the exact `PixelAutoencoder` of pixel-space
            models (`VAEConfig.kind="pixel"`).
        image_encoder: CLIP vision tower with projection (frozen in training).
    """

    config: ModelConfig
    unet: UNet2DConditionModel
    vae: AutoencoderKL | PixelAutoencoder
    image_encoder: CLIPVisionModelWithProjection

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> "NeuralGafferModel":
        """Move every module in place to `device` and/or `dtype`; returns `self`."""
        for module in (self.unet, self.vae, self.image_encoder):
            # plain nn.Module.to: diffusers' override only adds a log line about keep-in-fp32 modules,
            # of which these models have none
            torch.nn.Module.to(module, device=device, dtype=dtype)
        return self

    def eval(self) -> "NeuralGafferModel":
        """Put every module in eval mode; returns `self`."""
        for module in (self.unet, self.vae, self.image_encoder):
            module.eval()
        return self

    def diffusion_target(
        self, latents: Float[Tensor, "N 4 h w"], image_latents: Float[Tensor, "N 4 h w"]
    ) -> Float[Tensor, "N 4 h w"]:
        """z_0, what the UNet denoises, from the raw VAE latents of the target and of the input.

        The target's latent (minus the input's when `config.residual`), times the VAE scaling factor:
        only this latent is scaled, never the conditioning latents (official implementation §1).
        """
        if self.config.residual and self.config.residual_space == "log_linear":
            z = _log_linear(latents) - _log_linear(image_latents)
        else:
            z = latents - image_latents if self.config.residual else latents
        return z * self.config.vae.scaling_factor

    def decodable_latents(
        self, z0: Float[Tensor, "N 4 h w"], image_latents: Float[Tensor, "N 4 h w"]
    ) -> Float[Tensor, "N 4 h w"]:
        """The inverse of `diffusion_target`: the raw VAE latents to decode from a sample z_0."""
        raw = z0 / self.config.vae.scaling_factor
        if self.config.residual and self.config.residual_space == "log_linear":
            return _from_log_linear(_log_linear(image_latents) + raw)
        return raw + image_latents if self.config.residual else raw

    @property
    def device(self) -> torch.device:
        """Device of the UNet's first parameter."""
        return next(self.unet.parameters()).device

    @property
    def dtype(self) -> torch.dtype:
        """Dtype of the UNet's first parameter."""
        return next(self.unet.parameters()).dtype


LOG_LINEAR_EPS = 0.02
"""Linear radiance added before the log of `residual_space` "log_linear": keeps the ratio finite on
black pixels and damps the noise of dark ones (sRGB 0.15 is linear 0.02)."""


def _log_linear(pixels: Float[Tensor, "N 4 h w"]) -> Float[Tensor, "N 4 h w"]:
    """log(linear + eps) of pixel-space latents in [-1, 1] (display sRGB, channels R, G, B, luma)."""
    lin = srgb_to_linear((pixels.float() + 1.0) * 0.5)
    return torch.log(lin + LOG_LINEAR_EPS).to(pixels.dtype)


def _from_log_linear(log_lin: Float[Tensor, "N 4 h w"]) -> Float[Tensor, "N 4 h w"]:
    """The inverse of `_log_linear` (clipped to the display range)."""
    x = linear_to_srgb(torch.exp(log_lin.float()) - LOG_LINEAR_EPS)
    return (x * 2.0 - 1.0).to(log_lin.dtype)


def vae_posterior(
    vae: AutoencoderKL | PixelAutoencoder, x: Float[Tensor, "N 3 H W"]
) -> DiagonalGaussianDistribution | PixelPosterior:
    """`vae.encode(x).latent_dist`: the posterior over the latents of images `x` in [-1, 1]."""
    out = vae.encode(x)
    # diffusers' encode returns the bare `(posterior,)` tuple only with return_dict=False
    return out[0] if isinstance(out, tuple) else out.latent_dist


def vae_decode(
    vae: AutoencoderKL | PixelAutoencoder, z: Float[Tensor, "N 4 h w"]
) -> Float[Tensor, "N 3 H W"]:
    """`vae.decode(z).sample`: images in [-1, 1] from raw (unscaled) latents."""
    if isinstance(vae, PixelAutoencoder):
        return vae.decode(z).sample
    # diffusers annotates `z` as the legacy `torch.FloatTensor` and the result as `DecoderOutput |
    # FloatTensor`; decode takes any float Tensor and, with return_dict=True, returns a DecoderOutput
    return cast(DecoderOutput, vae.decode(cast(torch.FloatTensor, z))).sample
