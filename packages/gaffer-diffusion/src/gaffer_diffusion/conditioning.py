"""Conditioning of the relighting UNet (paper §3.2, official implementation §1).

The UNet input is the channel concatenation `[z_t, E(x), E(E_H), E(E_L)]` (4 latent channels each):

- `E(x)`: VAE latent of the input image x,
- `E(E_H)`: VAE latent of the log-normalised HDR map of the target lighting, rotated into the camera frame,
- `E(E_L)`: VAE latent of the LDR (tone-mapped) map of the same lighting.

The three conditioning images are mapped from [0, 1] to [-1, 1] and encoded in ONE batched VAE call.
Their latents are raw posterior latents (NOT multiplied by the VAE scaling factor, which applies only to
z_t) and by default the posterior mode (deterministic); `latent_mode="sample"` draws posterior samples as
the authors' inference does. The cross-attention context is the CLIP image embedding of x, `[B, 1, D]`
(D = 768 for ViT-L/14), with the authors' preprocessing: bicubic resize (align_corners=True, no
antialias), [-1, 1] -> [0, 1], OpenAI mean/std.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion._choices import LatentMode as LatentMode  # the CLI's choices, torch-free
from gaffer_diffusion._validate import check_image_batch, check_unit_range
from gaffer_diffusion.errors import MissingDependencyError, ShapeError
from gaffer_diffusion.models.model import NeuralGafferModel, vae_posterior
from gaffer_diffusion.photo_encoding import (
    PhotoEncodingCache,
    clip_embedding,
    encode_photo,
    photo_groups,
    with_photos,
)
from gaffer_diffusion.photo_encoding import clip_preprocess as clip_preprocess  # defined there
from gaffer_envmap.compat_mode import Compat
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.poses import W2CBlender
from gaffer_envmap.rotate import Filter

LIGHTING_FILTER: Filter = "area"
"""The rotation filter of the lighting maps a model is trained and sampled with (gaffer-envmap's
`encode_lighting(filter=...)`). gaffer-tiny was trained on maps rotated by the area filter (supersample
2), which was gaffer-envmap's default until the power-exact "conservative" filter became the default;
a model must see at sampling time what it saw in training (the demo lost 1.2 dB when gaffer-tiny was
fed conservative maps), so gaffer-diffusion names its filter here instead of following the library's
default. A model retrained on conservative maps would change this together with its weights."""
LIGHTING_SUPERSAMPLE = 2
"""Sub-samples per output pixel side of `LIGHTING_FILTER` (its training setting)."""

CompatMode = Compat
"""gaffer-envmap's lighting encoding (`gaffer_envmap.Compat`, defined there once)."""

if TYPE_CHECKING:
    from gaffer_diffusion.hints import HintGeometry

    _Images = Float[Tensor, "B 3 H W"]
    _Masks = Float[Tensor, "B 1 H W"]
else:  # `LightingMaps` / `RelightingConditions.__post_init__` check these shapes themselves (a
    # ShapeError naming the field and the fix), so at run time the fields take any tensor and the
    # test-time type hook does not refuse first
    _Images = _Masks = Tensor


@dataclass(frozen=True, kw_only=True)
class LightingMaps:
    """Camera-frame lighting maps of the target lighting (the paper's E_L and E_H).

    Attributes:
        ldr: `[B, 3, H, W]` LDR map E_L in [0, 1].
        hdr: `[B, 3, H, W]` log-normalised HDR map E_H in [0, 1].

    Raises:
        ShapeError: on wrong or different shapes.
        InputValueError: on NaN/Inf or values outside [0, 1].
    """

    ldr: _Images
    hdr: _Images

    def __post_init__(self) -> None:
        check_image_batch("ldr", self.ldr)
        check_image_batch("hdr", self.hdr)
        if self.ldr.shape != self.hdr.shape:
            raise ShapeError(
                "hdr", tuple(self.hdr.shape), f"the shape of `ldr` {tuple(self.ldr.shape)}"
            )
        object.__setattr__(self, "ldr", check_unit_range("ldr", self.ldr))
        object.__setattr__(self, "hdr", check_unit_range("hdr", self.hdr))

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.ldr.shape[0])


@dataclass(frozen=True, kw_only=True)
class RelightingConditions:
    """What the relighting model is conditioned on, before encoding.

    Attributes:
        image: `[B, 3, H, W]` input image x in [0, 1] (sRGB, object on a white background).
        lighting: target lighting maps, same B, H, W as `image`.
        mask: optional `[B, 1, H, W]` object mask of `image` in [0, 1] (its alpha). When given,
            `RelightPipeline.__call__` keeps the input outside the object: relit = x + mask * (y - x)
            for the model's output y. Relighting a fixed view does not move the silhouette, so
            whatever the model paints on the background is error (gaffer-tiny: +0.15 dB PSNR on
            held-out renders). None: the model's full frame, as the authors score it.
        normals: optional `[B, 3, H, W]` camera-frame unit normals of the input (x right, y up, z
            toward the camera) for the radiance hints of a model with `hint_geometry` "estimated",
            in place of the estimator's: the true normals of a render give the oracle ceiling of the
            re-shading benchmark. None: the model's own geometry.

    Raises:
        ShapeError: when shapes disagree.
        InputValueError: on NaN/Inf or values outside [0, 1].

    Example:
        >>> import torch
        >>> x = torch.rand(2, 3, 64, 64)
        >>> c = RelightingConditions(image=x, lighting=LightingMaps(ldr=x, hdr=x))
        >>> c.batch_size
        2
    """

    image: _Images
    lighting: LightingMaps
    mask: _Masks | None = None
    normals: _Images | None = None

    def __post_init__(self) -> None:
        check_image_batch("image", self.image)
        if self.normals is not None and tuple(self.normals.shape) != tuple(self.image.shape):
            raise ShapeError(
                "normals",
                tuple(self.normals.shape),
                f"the shape of `image` {tuple(self.image.shape)}",
                "Pass camera-frame normals at the model resolution.",
            )
        object.__setattr__(self, "image", check_unit_range("image", self.image))
        if self.mask is not None:
            check_image_batch("mask", self.mask, channels=1)
            if (
                self.mask.shape[0] != self.image.shape[0]
                or self.mask.shape[2:] != self.image.shape[2:]
            ):
                raise ShapeError(
                    "mask",
                    tuple(self.mask.shape),
                    f"[B, 1, H, W] matching `image` {tuple(self.image.shape)}",
                    "Pass the input's alpha at the model resolution (`PreparedImage.mask`).",
                )
            object.__setattr__(self, "mask", check_unit_range("mask", self.mask))
        if tuple(self.image.shape) != tuple(self.lighting.ldr.shape):
            raise ShapeError(
                "lighting.ldr",
                tuple(self.lighting.ldr.shape),
                f"the shape of `image` {tuple(self.image.shape)}",
                "Encode the lighting at the image resolution (`encode_lighting(..., size=H)`).",
            )

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.image.shape[0])


@dataclass(frozen=True, kw_only=True)
class EncodedConditions:
    """Conditioning after the VAE and CLIP encoders; constant across seeds and denoising steps.

    Attributes:
        image_latents: `[B, 4, h, w]` raw (unscaled) latent of the input image.
        hdr_latents: `[B, 4, h, w]` raw latent of the HDR map E_H.
        ldr_latents: `[B, 4, h, w]` raw latent of the LDR map E_L.
        clip_embeds: `[B, 1, D]` CLIP image embedding of the input (the cross-attention context).
        hints: `[B, 12, h, w]` radiance hints (`gaffer_diffusion.hints`) for a model with
            `ModelConfig.hints`, else None.
    """

    image_latents: Float[Tensor, "B 4 h w"]
    hdr_latents: Float[Tensor, "B 4 h w"]
    ldr_latents: Float[Tensor, "B 4 h w"]
    clip_embeds: Float[Tensor, "B 1 D"]
    hints: Float[Tensor, "B K h w"] | None = None

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.image_latents.shape[0])

    def concat_latents(self) -> Float[Tensor, "B C h w"]:
        """`[E(x), E(E_H), E(E_L)]` (+ the hints) along channels, the order the UNet was trained with."""
        parts = [self.image_latents, self.hdr_latents, self.ldr_latents]
        if self.hints is not None:
            parts.append(self.hints)
        return torch.cat(parts, dim=1)

    @staticmethod
    def cat(parts: "Sequence[EncodedConditions]") -> "EncodedConditions":
        """The items of several `EncodedConditions` in one batch, in order."""
        hints = [p.hints for p in parts]
        return EncodedConditions(
            image_latents=torch.cat([p.image_latents for p in parts]),
            hdr_latents=torch.cat([p.hdr_latents for p in parts]),
            ldr_latents=torch.cat([p.ldr_latents for p in parts]),
            clip_embeds=torch.cat([p.clip_embeds for p in parts]),
            hints=None if any(h is None for h in hints) else torch.cat(hints),  # type: ignore[arg-type]
        )

    def _map(self, fn: Any) -> "EncodedConditions":
        return EncodedConditions(
            image_latents=fn(self.image_latents),
            hdr_latents=fn(self.hdr_latents),
            ldr_latents=fn(self.ldr_latents),
            clip_embeds=fn(self.clip_embeds),
            hints=None if self.hints is None else fn(self.hints),
        )

    def repeat_interleave(self, repeats: int) -> "EncodedConditions":
        """Each item repeated `repeats` times in place (item0, item0, item1, ...): several seeds."""
        return self._map(lambda t: t.repeat_interleave(repeats, dim=0))

    def select(self, indices: Tensor | list[int]) -> "EncodedConditions":
        """The items at `indices` (a subset of the batch)."""
        idx = torch.as_tensor(indices, dtype=torch.long, device=self.image_latents.device)
        return self._map(lambda t: t[idx])

    def to(
        self, device: torch.device | str | None = None, dtype: torch.dtype | None = None
    ) -> "EncodedConditions":
        """A copy on another device and/or dtype."""
        return self._map(lambda t: t.to(device=device, dtype=dtype))


@torch.no_grad()
def encode_conditions(
    model: NeuralGafferModel,
    conditions: RelightingConditions,
    *,
    latent_mode: LatentMode = "mode",
    generator: torch.Generator | Sequence[torch.Generator] | None = None,
    photo_cache: "PhotoEncodingCache | None" = None,
) -> EncodedConditions:
    """Encode the input image and lighting maps (one batched VAE call) and the CLIP embedding.

    A batch in which photos repeat (one photo under many lightings) encodes each photo once; with
    `photo_cache` the next batch of the same photo reuses it (`gaffer_diffusion.photo_encoding`).

    Args:
        model: the networks; inputs are cast to the VAE's / CLIP's device and dtype.
        conditions: `[B, 3, H, W]` image and maps in [0, 1], H = W = `model.config.resolution`.
        latent_mode: "mode" (default, deterministic) or "sample" (the authors' inference).
        photo_cache: keeps the photo's encodings for the next call with the same photo.
        generator: RNG for `latent_mode="sample"`: one, or a list of B (one per item; item b's
            generator draws its image, HDR and LDR posterior noise in that order, so an item's
            latents do not depend on the rest of the batch).

    Returns:
        Raw latents `[B, 4, h, w]` each and CLIP embeddings `[B, 1, D]`.

    Raises:
        ShapeError: when the images are not `resolution x resolution`.
    """
    res = model.config.resolution
    if tuple(conditions.image.shape[2:]) != (res, res):
        raise ShapeError(
            "conditions.image",
            tuple(conditions.image.shape),
            f"[B, 3, {res}, {res}] (the model's resolution)",
            "Preprocess with `gaffer_diffusion.preprocess.prepare_object_image(..., size=res)`.",
        )
    vae_param = next(model.vae.parameters())
    b = conditions.batch_size
    photos = None
    first, group = photo_groups(conditions.image)
    if len(first) < b or photo_cache is not None:
        # each distinct photo encoded once, alone: batch 1 whatever the batch, so that relighting a
        # folder in batches of 4 gives the images it gives one at a time
        photos = [
            photo_cache.get(model, conditions.image[i : i + 1])
            if photo_cache is not None
            else encode_photo(model, conditions.image[i : i + 1])
            for i in first
        ]
        # [2B, 3, H, W]  HDR, LDR in one batch; the photos' posteriors join them as items 0..B-1
        stacked = torch.cat([conditions.lighting.hdr, conditions.lighting.ldr], dim=0)
        stacked = (stacked * 2.0 - 1.0).to(device=vae_param.device, dtype=vae_param.dtype)
        posterior = with_photos(
            [p.posterior for p in photos], group, vae_posterior(model.vae, stacked)
        )
    else:
        # [3B, 3, H, W]  image, HDR, LDR in one batch, mapped [0, 1] -> [-1, 1] for the VAE
        stacked = torch.cat(
            [conditions.image, conditions.lighting.hdr, conditions.lighting.ldr], dim=0
        )
        stacked = (stacked * 2.0 - 1.0).to(device=vae_param.device, dtype=vae_param.dtype)
        posterior = vae_posterior(model.vae, stacked)
    match latent_mode:
        case "mode":
            latents = posterior.mode()
        case "sample":
            gen: Any = generator
            if generator is not None and not isinstance(generator, torch.Generator):
                gen = list(generator)
                if len(gen) != b:
                    raise ShapeError("generator", (len(gen),), f"[{b}] (one generator per item)")
                gen = gen * 3  # [3B]: image, HDR, LDR; each item's generator draws them in turn
            latents = posterior.sample(generator=gen)
    # [3B, 4, h, w] -> three [B, 4, h, w]; raw posterior latents (no scaling factor, official impl. §1)
    image_latents, hdr_latents, ldr_latents = latents.split(b, dim=0)

    if photos is not None:
        clip_all = torch.cat([p.clip_embeds for p in photos])  # [G, 1, D]
        clip_embeds = clip_all[torch.tensor(group, device=clip_all.device)]  # [B, 1, D]
    else:
        clip_embeds = clip_embedding(model, conditions.image)  # [B, 1, D]
    hints = None
    if model.config.hints:
        hints = hints_for(
            conditions, model.config.latent_size, geometry=model.config.hint_geometry
        ).to(device=vae_param.device, dtype=image_latents.dtype)
    return EncodedConditions(
        image_latents=image_latents,
        hdr_latents=hdr_latents,
        ldr_latents=ldr_latents,
        clip_embeds=clip_embeds,
        hints=hints,
    )


def object_mask_of(image: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B 1 H W"]:
    """A stand-in object mask for an image on white without its alpha: pixels not pure white."""
    return (image.amin(dim=1, keepdim=True) < 254.5 / 255.0).float()


def hints_for(
    conditions: RelightingConditions, size: int, *, geometry: "HintGeometry" = "silhouette"
) -> Float[Tensor, "B C s s"]:
    """Radiance hints (`gaffer_diffusion.hints.relighting_hints`) of `conditions` at `size` px.

    The mask is `conditions.mask` (the input's alpha), else the pixels of the input that are not
    pure white; latent models get the hints area-downsampled to their latent size. `geometry`
    "estimated" (`ModelConfig.hint_geometry`): normals from the learned estimator and the de-lit
    ratio of the input (15 channels), else the silhouette dome (12).
    """
    from gaffer_diffusion.geometry import input_normals
    from gaffer_diffusion.hints import hints_at

    mask = conditions.mask if conditions.mask is not None else object_mask_of(conditions.image)
    image = conditions.image.float()
    normals = None
    if geometry == "estimated":
        normals = conditions.normals
        if normals is None:
            normals = input_normals(geometry, image, mask.float())
    return hints_at(
        mask.float(),
        conditions.lighting.ldr,
        conditions.lighting.hdr,
        size,
        geometry=geometry,
        image=image,
        normals=normals,
    )


def lighting_from_envmap(
    env: EnvironmentMap | Sequence[EnvironmentMap] | np.ndarray | Tensor,
    w2c_blender: Float[Tensor, "B 3 4"] | Float[Tensor, "B 3 3"] | W2CBlender | Sequence[Any],
    *,
    size: int = 256,
    compat: CompatMode = "neural-gaffer",
    spin_deg: float | Tensor = 0.0,
) -> LightingMaps:
    """Camera-frame LDR/HDR maps of an environment map via `gaffer_envmap.encode.encode_lighting`.

    Neural Gaffer §3.2: the map is rotated into the target camera frame and split into E_L and E_H.
    `compat="neural-gaffer"` (the default here) reproduces the maps the released checkpoint was trained
    with (official implementation §4).

    Args:
        env: a `gaffer_envmap.EnvironmentMap` (or one per item), or `[He, We, 3]` linear radiance.
        w2c_blender: `[B, 3, 4]` or `[B, 3, 3]` world-to-camera matrices in Blender's camera convention,
            or one `gaffer_envmap.W2CBlender` pose or a sequence of them.
        size: side length of the square maps (the model resolution).
        compat: encoding mode of gaffer-envmap.
        spin_deg: extra spin of the light about world up (turntables), scalar or `[B]`.

    Returns:
        `LightingMaps` with `[B, 3, size, size]` maps in [0, 1].

    Raises:
        MissingDependencyError: when gaffer-envmap's encoder is not importable.
    """
    try:
        from gaffer_envmap.encode import encode_lighting
    except ImportError as exc:
        raise MissingDependencyError(
            "Encoding an environment map needs `gaffer_envmap.encode` (gaffer-envmap>=0.1,<0.2): "
            'pip install "gaffer-envmap>=0.1,<0.2". Alternatively pass already-encoded `LightingMaps`.'
        ) from exc
    encoding = encode_lighting(
        env,
        w2c_blender,
        size=size,
        compat=compat,
        spin_deg=spin_deg,
        filter=LIGHTING_FILTER,
        supersample=LIGHTING_SUPERSAMPLE,
    )
    return LightingMaps(ldr=encoding.ldr.float(), hdr=encoding.hdr.float())
