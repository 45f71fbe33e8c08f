"""The input photo's encodings (VAE posterior, CLIP embedding), computed once per photo,
so relighting one photo under many lightings pays one VAE and one CLIP encoder call.

Relighting one photo under many lightings (a folder of maps, the turntable's frames, a batch of seeds)
repeats the same input image in every item; only the lighting maps differ. `encode_conditions` asks
`photo_encoding` for each distinct photo's VAE posterior and CLIP embedding: a batch encodes each
photo once, alone (so an item's latents do not depend on which other items share its batch), and a
`PhotoEncodingCache` (held by `RelightPipeline`) keeps the last one for the next batch. On the paper-size model in float32 the photo's share of the conditioning
encode is a third of the VAE call and all of CLIP (`benchmarks/results/diffusion_speed.json`).
"""

import hashlib
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from diffusers.models.autoencoders.vae import DiagonalGaussianDistribution
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.configs import CLIP_MEAN, CLIP_STD
from gaffer_diffusion.models.model import NeuralGafferModel, vae_posterior
from gaffer_diffusion.models.pixel import PixelPosterior

Posterior = DiagonalGaussianDistribution | PixelPosterior


def photo_groups(images: Float[Tensor, "B 3 H W"]) -> tuple[list[int], list[int]]:
    """Which items show the same photo: `(first, group)`, where `first[g]` is the index of the first
    item of photo g and `group[i]` the photo of item i (an expanded tensor is one photo, at no cost)."""
    if images.shape[0] < 2 or images.stride(0) == 0:
        return [0], [0] * images.shape[0]
    first: list[int] = []
    group: list[int] = []
    for i in range(images.shape[0]):
        g = next((k for k, j in enumerate(first) if torch.equal(images[i], images[j])), None)
        if g is None:
            g = len(first)
            first.append(i)
        group.append(g)
    return first, group


def _key(photo: Tensor, model: NeuralGafferModel) -> tuple[int, str, str, str]:
    """The photo's content and the networks it went through (their identity, device and dtype)."""
    data = photo.detach().to("cpu", torch.float32).contiguous().numpy().tobytes()
    digest = hashlib.blake2b(data, digest_size=16).hexdigest()
    param = next(model.vae.parameters(), None) if hasattr(model.vae, "parameters") else None
    where = f"{model.device}/{model.dtype}/{None if param is None else param.dtype}"
    return (id(model), digest, where, str(tuple(photo.shape)))


@dataclass(frozen=True, kw_only=True)
class PhotoEncoding:
    """One photo's encodings: its VAE posterior (batch 1) and CLIP embedding `[1, 1, D]`."""

    posterior: Posterior
    clip_embeds: Float[Tensor, "1 1 D"]


class PhotoEncodingCache:
    """The last photo's `PhotoEncoding`, reused while the same photo comes again (one entry: a run
    relights one photo at a time, and the entry's tensors are small)."""

    def __init__(self) -> None:
        self._key: tuple[int, str, str, str] | None = None
        self._value: PhotoEncoding | None = None
        self.hits = 0
        self.misses = 0

    def get(self, model: NeuralGafferModel, photo: Tensor) -> PhotoEncoding:
        """The encoding of `photo` `[1, 3, H, W]` in [0, 1], from the cache or computed now."""
        key = _key(photo, model)
        if key == self._key and self._value is not None:
            self.hits += 1
            return self._value
        self.misses += 1
        value = encode_photo(model, photo)
        self._key, self._value = key, value
        return value


def clip_preprocess(
    image_pm1: Float[Tensor, "B 3 H W"], image_size: int
) -> Float[Tensor, "B 3 S S"]:
    """The authors' CLIP preprocessing of an image in [-1, 1] (official implementation §1).

    Bicubic resize to `image_size` (align_corners=True, no antialias), [-1, 1] -> [0, 1], then the OpenAI
    mean/std normalisation.

    Args:
        image_pm1: `[B, 3, H, W]` image in [-1, 1].
        image_size: CLIP input side length (224 for ViT-L/14).

    Returns:
        `[B, 3, image_size, image_size]` normalised pixel values.
    """
    x = F.interpolate(
        image_pm1,
        size=(image_size, image_size),
        mode="bicubic",
        align_corners=True,
        antialias=False,
    )
    x = (x + 1.0) / 2.0
    mean = torch.tensor(CLIP_MEAN, device=x.device, dtype=x.dtype).view(1, 3, 1, 1)
    std = torch.tensor(CLIP_STD, device=x.device, dtype=x.dtype).view(1, 3, 1, 1)
    return (x - mean) / std


def clip_embedding(
    model: NeuralGafferModel, images: Float[Tensor, "B 3 H W"]
) -> Float[Tensor, "B 1 D"]:
    """The CLIP image embedding `[B, 1, D]` of images in [0, 1] (`conditioning.clip_preprocess`)."""
    enc_param = next(model.image_encoder.parameters())
    pixels = clip_preprocess(
        images.to(device=enc_param.device, dtype=enc_param.dtype) * 2.0 - 1.0,
        model.config.image_encoder.image_size,
    )
    return model.image_encoder(pixel_values=pixels).image_embeds.unsqueeze(1)


@torch.no_grad()
def encode_photo(model: NeuralGafferModel, photo: Float[Tensor, "1 3 H W"]) -> PhotoEncoding:
    """The VAE posterior and CLIP embedding of one photo in [0, 1]."""
    vae_param = next(model.vae.parameters(), None)
    dtype = model.dtype if vae_param is None else vae_param.dtype
    x = (photo * 2.0 - 1.0).to(device=model.device, dtype=dtype)
    return PhotoEncoding(
        posterior=vae_posterior(model.vae, x), clip_embeds=clip_embedding(model, photo)
    )


def with_photos(photos: list[Posterior], group: list[int], lighting: Posterior) -> Posterior:
    """One posterior of `[photo of item 0..B-1, lighting (2 x B)]`, as if the three had been encoded in
    one VAE call: a posterior sample then draws each item's noise in the same order as before.

    Args:
        photos: each distinct photo's posterior (batch 1).
        group: `group[i]` is the photo of item i (`photo_groups`).
        lighting: the HDR and LDR maps' posterior, `2 x B` items.
    """
    index = torch.tensor(group)
    if all(isinstance(p, PixelPosterior) for p in photos) and isinstance(lighting, PixelPosterior):
        lat = torch.cat([p.latents for p in photos if isinstance(p, PixelPosterior)])
        return PixelPosterior(torch.cat([lat[index.to(lat.device)], lighting.latents]))
    if all(isinstance(p, DiagonalGaussianDistribution) for p in photos) and isinstance(
        lighting, DiagonalGaussianDistribution
    ):
        par = torch.cat(
            [p.parameters for p in photos if isinstance(p, DiagonalGaussianDistribution)]
        )
        return DiagonalGaussianDistribution(
            torch.cat([par[index.to(par.device)], lighting.parameters])
        )
    kinds = sorted({type(p).__name__ for p in [*photos, lighting]})
    raise TypeError(f"posteriors of several kinds: {kinds}")
