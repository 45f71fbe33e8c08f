"""Public test helpers: tiny random models, random conditions and fake checkpoint folders.

Sibling packages and e2e tests import these (tests run with `--import-mode=importlib`). Nothing here
downloads anything: every model is a random-initialised `tiny` preset.
"""

import dataclasses
import json
from pathlib import Path

import torch
from safetensors.torch import save_file

from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
from gaffer_diffusion.configs import ModelConfig, get_preset
from gaffer_diffusion.models.build import build_model, build_unet
from gaffer_diffusion.models.model import NeuralGafferModel


def tiny_model(seed: int = 0) -> NeuralGafferModel:
    """The `tiny` preset with random weights (float32, CPU, eval mode)."""
    return build_model(get_preset("tiny"), seed=seed)


def random_conditions(
    batch_size: int = 1, resolution: int = 64, *, seed: int = 0
) -> RelightingConditions:
    """Random `[B, 3, R, R]` image and lighting maps in [0, 1] standing in for real inputs."""
    g = torch.Generator().manual_seed(seed)
    shape = (batch_size, 3, resolution, resolution)
    return RelightingConditions(
        image=torch.rand(shape, generator=g),
        lighting=LightingMaps(
            ldr=torch.rand(shape, generator=g), hdr=torch.rand(shape, generator=g)
        ),
    )


def write_fake_zero123(
    model: NeuralGafferModel, directory: Path, *, unet_in_channels: int = 8, seed: int = 1
) -> Path:
    """A fake Zero-1-to-3 XL diffusers folder holding `model`'s VAE and CLIP encoder.

    Its UNet has `model`'s shapes but `unet_in_channels` inputs (Zero123: 8) and its own random weights,
    like the real base model whose UNet the released checkpoint replaces.
    """
    directory.mkdir(parents=True, exist_ok=True)
    cfg = dataclasses.replace(model.config.unet, in_channels=unet_in_channels)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        unet = build_unet(cfg)
    unet.save_pretrained(directory / "unet", safe_serialization=True)
    model.vae.save_pretrained(directory / "vae", safe_serialization=True)
    model.image_encoder.save_pretrained(directory / "image_encoder", safe_serialization=True)
    (directory / "scheduler").mkdir(exist_ok=True)
    sched = {"_class_name": "DDIMScheduler", **dataclasses.asdict(model.config.scheduler)}
    (directory / "scheduler" / "scheduler_config.json").write_text(json.dumps(sched))
    (directory / "model_index.json").write_text(
        json.dumps({"_class_name": "Zero1to3StableDiffusionPipeline"})
    )
    return directory


def write_fake_authors_checkpoint(
    model: NeuralGafferModel, directory: Path, *, file_format: str = "safetensors"
) -> Path:
    """A fake `checkpoint-80000/` folder: `model`'s UNet state dict only, as accelerate saves it.

    Args:
        model: whose UNet to save.
        directory: the folder to create (name it `checkpoint-80000` to mirror the release).
        file_format: "safetensors" (`model.safetensors`) or "bin" (`pytorch_model.bin`).
    """
    directory.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().clone().contiguous() for k, v in model.unet.state_dict().items()}
    if file_format == "safetensors":
        save_file(state, str(directory / "model.safetensors"))
    else:
        torch.save(state, directory / "pytorch_model.bin")
    (directory / "random_states_0.pkl").write_bytes(b"")
    return directory


def tiny_config() -> ModelConfig:
    """The `tiny` preset config."""
    return get_preset("tiny")
