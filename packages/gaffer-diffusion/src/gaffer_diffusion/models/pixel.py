"""`PixelAutoencoder`: the exact, parameter-free "VAE" of pixel-space models (`VAEConfig.kind="pixel"`).

It stands where `diffusers.AutoencoderKL` stands in `NeuralGafferModel` and offers the part of its interface
the pipeline, the conditioning and the training loop use (`encode(x).latent_dist.mode()` / `.sample()`,
`decode(z).sample`, `config.scaling_factor`, `save_pretrained`), so a pixel-space model runs through the
same classes; only the config differs.

The "latent" of an image `x` in [-1, 1], `[N, 3, H, W]`, is `[N, 4, H, W]` at full resolution (downsampling
factor 1): the three RGB channels unchanged, then their Rec. 709 luminance `0.2126 R + 0.7152 G + 0.0722 B`
(also in [-1, 1]). Decoding takes the RGB channels, so `decode(encode(x)) == x` exactly.

Why luminance as the 4th channel: the UNet layout stays the paper's four 4-channel latents
(`[z_t, E(x), E(E_H), E(E_L)]`, 16 input channels) with no model change, and the encoder sees only the
RGB image it is given (no alpha mask reaches it for the HDR/LDR maps), so the 4th channel must be a
function of RGB. Luminance is that function with a meaning: relighting mostly changes shading, i.e.
brightness, and an explicit brightness channel in every conditioning image (input, HDR and LDR maps)
costs nothing. It is redundant, which is what keeps the decode exact and trivial.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from diffusers.configuration_utils import FrozenDict
from jaxtyping import Float
from torch import Tensor

PIXEL_CLASS_NAME = "PixelAutoencoder"
"""`_class_name` in a saved pixel autoencoder's `config.json` (how the loader recognises it)."""

LUMA_WEIGHTS: tuple[float, float, float] = (0.2126, 0.7152, 0.0722)
"""Rec. 709 luminance weights of the 4th latent channel."""


class PixelPosterior:
    """A deterministic stand-in for diffusers' `DiagonalGaussianDistribution`: mode = sample = latent."""

    def __init__(self, latents: Float[Tensor, "N 4 H W"]) -> None:
        self.latents = latents

    def mode(self) -> Float[Tensor, "N 4 H W"]:
        """The latent."""
        return self.latents

    def sample(self, generator: torch.Generator | None = None) -> Float[Tensor, "N 4 H W"]:
        """The latent (there is no posterior noise); `generator` is accepted and unused."""
        return self.latents

    def kl(self, other: object = None) -> Float[Tensor, " N"]:
        """Zero per item: the encoder adds no information to regularise."""
        return self.latents.new_zeros(self.latents.shape[0])


@dataclass(frozen=True)
class PixelEncoderOutput:
    """`encode()`'s result, shaped like diffusers' `AutoencoderKLOutput`."""

    latent_dist: PixelPosterior


@dataclass(frozen=True)
class PixelDecoderOutput:
    """`decode()`'s result, shaped like diffusers' `DecoderOutput`."""

    sample: Float[Tensor, "N 3 H W"]


class PixelAutoencoder(torch.nn.Module):
    """RGB in [-1, 1] <-> `[RGB, luminance]` at full resolution; exact and parameter-free.

    It holds one empty (0-element) parameter so that `next(module.parameters())` gives the device and
    dtype the model was moved to, as it does for `AutoencoderKL`.

    Args:
        sample_size: nominal image size (recorded in the config only).
        scaling_factor: the factor the training loop and the sampler apply to the target latent.

    Example:
        >>> ae = PixelAutoencoder()
        >>> x = torch.rand(2, 3, 8, 8) * 2 - 1
        >>> bool((ae.decode(ae.encode(x).latent_dist.mode()).sample == x).all())
        True
    """

    luma: Tensor  # a buffer, typed for nn.Module.__getattr__ (which says Tensor | Module)

    def __init__(self, *, sample_size: int = 64, scaling_factor: float = 1.0) -> None:
        super().__init__()
        self.anchor = torch.nn.Parameter(torch.zeros(0), requires_grad=False)
        self.register_buffer("luma", torch.tensor(LUMA_WEIGHTS).view(1, 3, 1, 1), persistent=False)
        self.config = FrozenDict(
            _class_name=PIXEL_CLASS_NAME,
            kind="pixel",
            in_channels=3,
            latent_channels=4,
            sample_size=int(sample_size),
            scaling_factor=float(scaling_factor),
        )

    @property
    def device(self) -> torch.device:
        """Where the (empty) anchor parameter lives, as diffusers' `ModelMixin.device` (what a
        `DiffusionPipeline` asks its components)."""
        return self.anchor.device

    @property
    def dtype(self) -> torch.dtype:
        """The anchor parameter's dtype, as diffusers' `ModelMixin.dtype`."""
        return self.anchor.dtype

    def encode(self, x: Float[Tensor, "N 3 H W"]) -> PixelEncoderOutput:
        """`[x, luminance(x)]`, `[N, 4, H, W]`, in the dtype of `x`."""
        luma = (x * self.luma.to(x.dtype)).sum(dim=1, keepdim=True)
        return PixelEncoderOutput(latent_dist=PixelPosterior(torch.cat([x, luma], dim=1)))

    def decode(self, z: Float[Tensor, "N 4 H W"]) -> PixelDecoderOutput:
        """The RGB channels of `z`; the luminance channel is dropped."""
        return PixelDecoderOutput(sample=z[:, :3])

    def save_pretrained(self, directory: str | Path, **_: Any) -> None:
        """Write `config.json` (there are no weights); extra keyword arguments are ignored."""
        import json

        out = Path(directory)
        out.mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(dict(self.config), indent=2))

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> "PixelAutoencoder":
        """Rebuild from a saved `config.json` dict."""
        return cls(
            sample_size=int(config.get("sample_size", 64)),
            scaling_factor=float(config.get("scaling_factor", 1.0)),
        )


def is_pixel_config(config: dict[str, Any]) -> bool:
    """True for a `config.json` written by `PixelAutoencoder.save_pretrained`."""
    return config.get("_class_name") == PIXEL_CLASS_NAME or config.get("kind") == "pixel"
