"""Random-initialised construction of the Neural Gaffer networks from a `ModelConfig` (no download)."""

import dataclasses
from typing import Any

import torch
from diffusers.models.autoencoders.autoencoder_kl import AutoencoderKL
from diffusers.models.unets.unet_2d_condition import UNet2DConditionModel
from diffusers.schedulers.scheduling_ddim import DDIMScheduler
from transformers import CLIPVisionConfig, CLIPVisionModelWithProjection

from gaffer_diffusion.configs import (
    ImageEncoderConfig,
    ModelConfig,
    SchedulerConfig,
    UNetConfig,
    VAEConfig,
)
from gaffer_diffusion.hints import HintGeometry
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.models.pixel import PixelAutoencoder


def build_unet(config: UNetConfig) -> UNet2DConditionModel:
    """A random-initialised `UNet2DConditionModel` with the given shapes."""
    return UNet2DConditionModel(**config.to_diffusers())


def unet_from_config(config: dict[str, Any]) -> UNet2DConditionModel:
    """`UNet2DConditionModel.from_config(config)`, typed: a random-initialised UNet of a diffusers
    `unet/config.json` (weights are loaded separately).

    diffusers annotates `from_config` as `Self | tuple[Self, dict]` (the tuple only with
    `return_unused_kwargs=True`, never passed here); this narrows it once for every caller.
    """
    unet = UNet2DConditionModel.from_config(config)
    if not isinstance(unet, UNet2DConditionModel):
        raise TypeError(f"UNet2DConditionModel.from_config returned a {type(unet).__name__}")
    return unet


def build_vae(config: VAEConfig) -> AutoencoderKL | PixelAutoencoder:
    """A random-initialised `AutoencoderKL` with the given shapes, or the `PixelAutoencoder` of
    `kind="pixel"` (no parameters)."""
    if config.kind == "pixel":
        return PixelAutoencoder(
            sample_size=config.sample_size, scaling_factor=config.scaling_factor
        )
    return AutoencoderKL(**config.to_diffusers())


def build_image_encoder(config: ImageEncoderConfig) -> CLIPVisionModelWithProjection:
    """A random-initialised `CLIPVisionModelWithProjection` with the given shapes."""
    return CLIPVisionModelWithProjection(CLIPVisionConfig(**config.to_transformers()))


def build_scheduler(config: SchedulerConfig) -> DDIMScheduler:
    """The authors' DDIM scheduler (official implementation §2) for the given schedule."""
    return DDIMScheduler(**config.to_diffusers())


def build_model(config: ModelConfig, *, seed: int = 0) -> NeuralGafferModel:
    """Build every network of `config` with random weights, deterministically from `seed`.

    Args:
        config: the shapes.
        seed: seed of a local torch generator state (the global RNG is restored afterwards).

    Returns:
        The model in float32, on the CPU, in eval mode.

    Example:
        >>> from gaffer_diffusion.configs import get_preset
        >>> model = build_model(get_preset("tiny"))
        >>> model.unet.conv_in.weight.shape
        torch.Size([32, 16, 3, 3])
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        unet = build_unet(config.unet)
        vae = build_vae(config.vae)
        image_encoder = build_image_encoder(config.image_encoder)
    return NeuralGafferModel(config=config, unet=unet, vae=vae, image_encoder=image_encoder).eval()


def _pick(cls: type, source: dict[str, Any]) -> dict[str, Any]:
    names = {f.name for f in dataclasses.fields(cls)}
    out = {k: (tuple(v) if isinstance(v, list) else v) for k, v in source.items() if k in names}
    return out


def config_from_modules(
    unet: UNet2DConditionModel,
    vae: AutoencoderKL | PixelAutoencoder,
    image_encoder: CLIPVisionModelWithProjection,
    scheduler_config: dict[str, Any] | None = None,
    *,
    name: str = "loaded",
    hints: bool = False,
    hint_geometry: HintGeometry = "silhouette",
) -> ModelConfig:
    """The `ModelConfig` that describes already-built modules (read from their own configs).

    Args:
        unet: the denoiser (its `config.in_channels` must be 16, or 16 + 12 with `hints`).
        vae: the autoencoder.
        image_encoder: the CLIP tower.
        scheduler_config: a diffusers scheduler config dict; None for the authors' defaults.
        name: label stored in the config.
        hints: the UNet takes radiance hints (`ModelConfig.hints`; only a manifest records it).
        hint_geometry: where the hints' normals come from (`ModelConfig.hint_geometry`; likewise).

    Raises:
        ConfigError: when the modules do not fit together.
    """
    if isinstance(vae, PixelAutoencoder):
        vae_config = VAEConfig(
            kind="pixel",
            scaling_factor=vae.config["scaling_factor"],
            sample_size=vae.config["sample_size"],
        )
    else:
        vae_cfg = _pick(VAEConfig, dict(vae.config))
        vae_cfg["block_out_channels"] = tuple(vae.config["block_out_channels"])
        vae_cfg.pop("kind", None)
        vae_config = VAEConfig(**vae_cfg)
    unet_config = UNetConfig(**_pick(UNetConfig, dict(unet.config)))
    enc_config = ImageEncoderConfig(**_pick(ImageEncoderConfig, image_encoder.config.to_dict()))
    sched = SchedulerConfig(**_pick(SchedulerConfig, dict(scheduler_config or {})))
    resolution = unet_config.sample_size * vae_config.downsampling_factor
    return ModelConfig(
        name=name,
        resolution=resolution,
        unet=unet_config,
        vae=vae_config,
        image_encoder=enc_config,
        scheduler=sched,
        hints=hints,
        hint_geometry=hint_geometry,
    )
