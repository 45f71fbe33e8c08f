"""A small learned estimator of camera-frame normals from one photo of an object and its mask.

Why: gaffer-tiny's radiance hints (`gaffer_diffusion.hints`) render the input's shape under the target
light. Normals of a dome inflated from the silhouette cannot say which facet of an object faces the
light, so a model fed them recolours the input instead of re-shading it. DiLightNet
(Zeng et al. 2024) renders its hints from an estimated geometry; this is the same idea at CPU scale: a
diffusers `UNet2DModel` (no time conditioning is used: the timestep is always 0) takes `[RGB on white,
mask, silhouette-dome normals]` and predicts a correction added to the dome before normalising (its
last convolution starts at zero, so an untrained estimator is the dome): the dome is right about the
outline and the overall bulge, the photo's shading says where the facets turn. Trained on gaffer-data's
normal passes (`gaffer_diffusion.training.normals`).

Frames and encodings: input display-space sRGB in [0, 1], object-centred at 128 px as every gaffer-tiny
path frames it; output unit normals in the camera frame of the hints (x right, y up, z toward the
camera), `(0, 0, 1)` outside the mask. Mirroring the input in x mirrors the output (the estimate is
averaged with its mirrored twin, so the hints' mirror symmetry stays exact).
"""

import json
from dataclasses import asdict, dataclass
from functools import lru_cache
from importlib import resources
from pathlib import Path

import torch
import torch.nn.functional as F
from diffusers.models.unets.unet_2d import UNet2DModel
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.errors import CheckpointNotFoundError, ConfigError
from gaffer_diffusion.hints import silhouette_normals

__all__ = [
    "ESTIMATOR_CONFIG_NAME",
    "NormalEstimator",
    "NormalEstimatorConfig",
    "estimate_normals",
    "load_normal_estimator",
    "shipped_normal_estimator",
    "shipped_normal_estimator_path",
]

ESTIMATOR_CONFIG_NAME = "gaffer_normals.json"
"""The estimator folder's manifest (our config; the UNet is diffusers' `save_pretrained` format)."""

_HOW = (
    "gaffer-normals ships inside gaffer-diffusion (`gaffer_diffusion/weights/gaffer-normals/`): "
    "reinstall the package, or train one with `gaffer-diffusion train-normals` (its MODEL_CARD.md "
    "has the command) and pass its folder."
)


@dataclass(frozen=True, kw_only=True)
class NormalEstimatorConfig:
    """Shapes of the estimator.

    Attributes:
        resolution: side of the square object-centred input it was trained at (inputs are resized to
            it and the normals back to the input's size).
        block_out_channels: widths of the UNet's levels.
        layers_per_block: ResNet blocks per level.
    """

    resolution: int = 128
    block_out_channels: tuple[int, ...] = (16, 32, 64, 96)
    layers_per_block: int = 1

    def __post_init__(self) -> None:
        factor = 2 ** (len(self.block_out_channels) - 1)
        if self.resolution <= 0 or self.resolution % factor:
            raise ConfigError(
                f"`resolution` is {self.resolution}; expected a positive multiple of {factor}."
            )


class NormalEstimator(torch.nn.Module):
    """`[RGB on white, mask, dome]` -> camera-frame unit normals (see the module docstring)."""

    def __init__(self, config: NormalEstimatorConfig) -> None:
        super().__init__()
        self.config = config
        n = len(config.block_out_channels)
        self.unet = UNet2DModel(
            sample_size=config.resolution,
            in_channels=7,
            out_channels=3,
            block_out_channels=config.block_out_channels,
            layers_per_block=config.layers_per_block,
            down_block_types=("DownBlock2D",) * n,
            up_block_types=("UpBlock2D",) * n,
            norm_num_groups=8,
            add_attention=False,
        )
        torch.nn.init.zeros_(self.unet.conv_out.weight)
        if self.unet.conv_out.bias is not None:
            torch.nn.init.zeros_(self.unet.conv_out.bias)

    def forward(
        self, image: Float[Tensor, "B 3 H W"], mask: Float[Tensor, "B 1 H W"]
    ) -> Float[Tensor, "B 3 H W"]:
        """Unit normals at the input's size, `(0, 0, 1)` outside `mask > 0.5` (no mirror average)."""
        h, w = image.shape[-2:]
        size = self.config.resolution
        if (h, w) != (size, size):
            image = F.interpolate(image, size=(size, size), mode="bilinear", antialias=True)
            small = F.interpolate(mask, size=(size, size), mode="bilinear", antialias=True)
        else:
            small = mask
        dome = silhouette_normals(small)
        x = torch.cat([(image * 2.0 - 1.0) * small, small * 2.0 - 1.0, dome * small], dim=1)
        t = torch.zeros(x.shape[0], device=x.device, dtype=torch.long)
        raw = dome + self.unet(x, t).sample.float()
        if (h, w) != (size, size):
            raw = F.interpolate(raw, size=(h, w), mode="bilinear")
        n = raw / raw.norm(dim=1, keepdim=True).clamp_min(1e-6)
        flat = torch.tensor([0.0, 0.0, 1.0], device=n.device).view(1, 3, 1, 1)
        return torch.where(mask > 0.5, n, flat)

    def save(self, directory: str | Path, *, extra: dict[str, object] | None = None) -> None:
        """Write `unet/` (diffusers) and `gaffer_normals.json` (config + `extra`, e.g. its metrics)."""
        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        self.unet.save_pretrained(out / "unet", safe_serialization=True)
        doc = {
            "schema": "gaffer.normal_estimator",
            "schema_version": "1.0",
            "config": asdict(self.config),
            **(extra or {}),
        }
        (out / ESTIMATOR_CONFIG_NAME).write_text(json.dumps(doc, indent=2) + "\n")


@torch.no_grad()
def estimate_normals(
    estimator: NormalEstimator,
    image: Float[Tensor, "B 3 H W"],
    mask: Float[Tensor, "B 1 H W"],
) -> Float[Tensor, "B 3 H W"]:
    """Camera-frame unit normals of `image` (on white, [0, 1]) inside `mask`, averaged with the
    estimate of the mirrored input (mirrored back, x negated), so that mirroring the input mirrors
    the normals exactly. Runs in float32 on the estimator's device; returns on `image`'s device."""
    dev = next(estimator.parameters()).device
    img = image.float().to(dev)
    msk = mask.float().to(dev)
    both = estimator(torch.cat([img, img.flip(-1)]), torch.cat([msk, msk.flip(-1)]))
    b = image.shape[0]
    mirrored = both[b:].flip(-1) * torch.tensor([-1.0, 1.0, 1.0], device=dev).view(1, 3, 1, 1)
    n = both[:b] + mirrored
    n = n / n.norm(dim=1, keepdim=True).clamp_min(1e-6)
    flat = torch.tensor([0.0, 0.0, 1.0], device=dev).view(1, 3, 1, 1)
    return torch.where(msk > 0.5, n, flat).to(image.device)


def load_normal_estimator(directory: str | Path) -> NormalEstimator:
    """Load an estimator folder written by `NormalEstimator.save` (float32, CPU, eval mode).

    Raises:
        CheckpointNotFoundError: the folder, its manifest or its weights are missing.
    """
    root = Path(directory)
    manifest = root / ESTIMATOR_CONFIG_NAME
    weights = root / "unet" / "diffusion_pytorch_model.safetensors"
    for needed, what in ((manifest, "the estimator manifest"), (weights, "the estimator weights")):
        if not needed.is_file():
            raise CheckpointNotFoundError(what, [needed], _HOW)
    doc = json.loads(manifest.read_text())
    cfg = doc.get("config", {})
    config = NormalEstimatorConfig(
        resolution=int(cfg.get("resolution", 128)),
        block_out_channels=tuple(int(c) for c in cfg.get("block_out_channels", (16, 32, 64, 96))),
        layers_per_block=int(cfg.get("layers_per_block", 1)),
    )
    est = NormalEstimator(config)
    est.unet = UNet2DModel.from_pretrained(str(root / "unet"), local_files_only=True)
    return est.eval()


def shipped_normal_estimator_path() -> Path:
    """The folder of the shipped estimator, gaffer-normals (it may be missing in a stripped install)."""
    return Path(str(resources.files("gaffer_diffusion").joinpath("weights", "gaffer-normals")))


@lru_cache(maxsize=1)
def shipped_normal_estimator() -> NormalEstimator:
    """The shipped estimator, loaded once per process (the hints of every path call it)."""
    return load_normal_estimator(shipped_normal_estimator_path())
