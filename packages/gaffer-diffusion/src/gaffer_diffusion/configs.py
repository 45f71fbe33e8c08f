"""Typed, frozen configurations of the Neural Gaffer model and its presets.

A `ModelConfig` describes every network of the model (UNet, VAE, CLIP image encoder, scheduler) with the
numbers diffusers and transformers need to build them. `gaffer_diffusion.build_model(config)` builds
random-initialised networks (no download); `gaffer_diffusion.loading` builds them from weights on disk.

Presets (`get_preset`):

- `"neural-gaffer-256"`: the authors' shapes (official implementation §1): an SD-1.x UNet with 16 input
  channels (`[z_t, E(image), E(HDR), E(LDR)]`, 4 each), cross-attention dim 768, the SD VAE
  (scaling factor 0.18215) and CLIP ViT-L/14 with its 768-d projection; images 256x256, latents 32x32.
- `"neural-gaffer-512"`: the same networks at 512x512 (latents 64x64). No released weights.
- `"tiny"`: a few hundred thousand parameters with the same structure (four 4-channel latents, a VAE with a
  downsampling factor of 8, a CLIP vision tower with a projection), 64x64 images: CPU tests run in
  milliseconds per forward.
- `"gaffer-tiny"`: the shipped small model we train ourselves on CPU (`gaffer_diffusion.pretrained`):
  pixel space (`VAEConfig(kind="pixel")`, 128x128 "latents" `[R, G, B, luminance]`), a ~3M-parameter
  UNet with attention at 16x16, v-prediction sampled with "trailing" timesteps, diffusing the residual
  target - input (`ModelConfig.residual`), radiance hints (`ModelConfig.hints`), and the `"tiny"` CLIP
  tower.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from gaffer_diffusion import _choices
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.hints import ESTIMATED_HINT_CHANNELS, HINT_CHANNELS, HintGeometry

PresetName = _choices.PresetName

VAEKind = Literal["autoencoder-kl", "pixel"]
ResidualSpace = Literal["display", "log_linear"]
"""How a residual model's target relates to its input (`ModelConfig.residual_space`)."""
"""What stands in the VAE's place: diffusers' `AutoencoderKL`, or the exact, parameter-free
`gaffer_diffusion.models.pixel.PixelAutoencoder` (pixel-space diffusion, downsampling factor 1)."""

VAE_KINDS: tuple[VAEKind, ...] = ("autoencoder-kl", "pixel")

if TYPE_CHECKING:
    _VAEKindArg = VAEKind
    _PresetArg = PresetName
else:  # at run time any str reaches `VAEConfig` and `get_preset`, which refuse an unknown one with a
    _VAEKindArg = _PresetArg = str  # ConfigError (also under the test-time type hook)

PREDICTION_TYPES: tuple[str, ...] = ("epsilon", "v_prediction", "sample")
"""What the UNet may predict (diffusers' `prediction_type`)."""

LATENT_CHANNELS = 4
"""Channels of one VAE latent; the UNet input is 4 of them: noisy target + 3 conditioning latents."""

CONDITIONING_LATENTS = 3
"""Number of conditioning latents concatenated after z_t: E(image), E(HDR), E(LDR)."""

CLIP_MEAN: tuple[float, float, float] = (0.48145466, 0.4578275, 0.40821073)
"""OpenAI CLIP normalisation mean (official implementation §1)."""

CLIP_STD: tuple[float, float, float] = (0.26862954, 0.26130258, 0.27577711)
"""OpenAI CLIP normalisation standard deviation (official implementation §1)."""


@dataclass(frozen=True, kw_only=True)
class UNetConfig:
    """Shapes of the denoising `diffusers.UNet2DConditionModel`.

    Attributes:
        sample_size: latent side length (image size / 8).
        in_channels: 16 for Neural Gaffer: noisy latent (4) + image, HDR and LDR latents (4 each).
        out_channels: 4 (epsilon of the noisy latent).
        block_out_channels: channels per resolution level.
        layers_per_block: ResNet layers per level.
        down_block_types: diffusers block names, top to bottom.
        up_block_types: diffusers block names, bottom to top.
        attention_head_dim: SD-1.x's (mis-named) number of heads, 8.
        cross_attention_dim: width of the cross-attention context, the CLIP projection dim.
        norm_num_groups: GroupNorm groups.
    """

    sample_size: int = 32
    in_channels: int = 16
    out_channels: int = 4
    block_out_channels: tuple[int, ...] = (320, 640, 1280, 1280)
    layers_per_block: int = 2
    down_block_types: tuple[str, ...] = (
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "DownBlock2D",
    )
    up_block_types: tuple[str, ...] = (
        "UpBlock2D",
        "CrossAttnUpBlock2D",
        "CrossAttnUpBlock2D",
        "CrossAttnUpBlock2D",
    )
    attention_head_dim: int = 8
    cross_attention_dim: int = 768
    norm_num_groups: int = 32

    def to_diffusers(self) -> dict[str, Any]:
        """Keyword arguments for `UNet2DConditionModel(**kwargs)`."""
        return {
            "sample_size": self.sample_size,
            "in_channels": self.in_channels,
            "out_channels": self.out_channels,
            "block_out_channels": self.block_out_channels,
            "layers_per_block": self.layers_per_block,
            "down_block_types": self.down_block_types,
            "up_block_types": self.up_block_types,
            "attention_head_dim": self.attention_head_dim,
            "cross_attention_dim": self.cross_attention_dim,
            "norm_num_groups": self.norm_num_groups,
        }


@dataclass(frozen=True, kw_only=True)
class VAEConfig:
    """Shapes of the `diffusers.AutoencoderKL` (the SD VAE by default), or the pixel-space stand-in.

    Attributes:
        kind: "autoencoder-kl" (default) or "pixel": the exact, parameter-free map of an RGB image in
            [-1, 1] to a 4-channel full-resolution "latent" `[R, G, B, luminance]` whose decode takes the
            RGB channels (`gaffer_diffusion.models.pixel`). With "pixel" the downsampling factor is 1 and
            only `latent_channels`, `scaling_factor` and `sample_size` are used.
        block_out_channels: encoder channels per level; the downsampling factor is 2**(levels - 1).
        layers_per_block: ResNet layers per level.
        latent_channels: 4.
        norm_num_groups: GroupNorm groups.
        scaling_factor: 0.18215, applied ONLY to the noisy/target latent (official implementation §1).
        sample_size: nominal image size.
    """

    kind: _VAEKindArg = "autoencoder-kl"
    block_out_channels: tuple[int, ...] = (128, 256, 512, 512)
    layers_per_block: int = 2
    latent_channels: int = LATENT_CHANNELS
    norm_num_groups: int = 32
    scaling_factor: float = 0.18215
    sample_size: int = 256

    def __post_init__(self) -> None:
        if self.kind not in VAE_KINDS:
            raise ConfigError(f"`vae.kind` is {self.kind!r}; expected one of {list(VAE_KINDS)}.")
        if not self.scaling_factor > 0:
            raise ConfigError(
                f"`vae.scaling_factor` is {self.scaling_factor}; it must be positive."
            )

    @property
    def downsampling_factor(self) -> int:
        """Image size / latent size (8 for the SD VAE, 1 for `kind="pixel"`)."""
        if self.kind == "pixel":
            return 1
        return 2 ** (len(self.block_out_channels) - 1)

    def to_diffusers(self) -> dict[str, Any]:
        """Keyword arguments for `AutoencoderKL(**kwargs)`.

        Raises:
            ConfigError: for `kind="pixel"`, which is not an `AutoencoderKL`.
        """
        if self.kind == "pixel":
            raise ConfigError(
                "`vae.kind` is 'pixel': there is no AutoencoderKL to build; use "
                "`gaffer_diffusion.models.build.build_vae`."
            )
        levels = len(self.block_out_channels)
        return {
            "in_channels": 3,
            "out_channels": 3,
            "down_block_types": ("DownEncoderBlock2D",) * levels,
            "up_block_types": ("UpDecoderBlock2D",) * levels,
            "block_out_channels": self.block_out_channels,
            "layers_per_block": self.layers_per_block,
            "latent_channels": self.latent_channels,
            "norm_num_groups": self.norm_num_groups,
            "sample_size": self.sample_size,
            "scaling_factor": self.scaling_factor,
        }


@dataclass(frozen=True, kw_only=True)
class ImageEncoderConfig:
    """Shapes of the `transformers.CLIPVisionModelWithProjection` (CLIP ViT-L/14 by default).

    Attributes:
        hidden_size: transformer width.
        intermediate_size: MLP width.
        num_hidden_layers: transformer depth.
        num_attention_heads: heads.
        image_size: input side length after the CLIP resize (224).
        patch_size: 14.
        projection_dim: width of `image_embeds`, the UNet's cross-attention context (768).
        hidden_act: "quick_gelu" for OpenAI CLIP.
    """

    hidden_size: int = 1024
    intermediate_size: int = 4096
    num_hidden_layers: int = 24
    num_attention_heads: int = 16
    image_size: int = 224
    patch_size: int = 14
    projection_dim: int = 768
    hidden_act: str = "quick_gelu"

    def to_transformers(self) -> dict[str, Any]:
        """Keyword arguments for `CLIPVisionConfig(**kwargs)`."""
        return dataclasses.asdict(self)


@dataclass(frozen=True, kw_only=True)
class SchedulerConfig:
    """The training noise schedule (official implementation §2), shared by every sampler.

    Attributes:
        num_train_timesteps: 1000.
        beta_start: 0.00085.
        beta_end: 0.012.
        beta_schedule: "scaled_linear".
        prediction_type: "epsilon" (the paper's), "v_prediction" or "sample" (x0): what the UNet
            predicts; the training loss and every sampler follow it.
        steps_offset: 1 (timesteps 981, 961, ..., 1 for 50 DDIM steps).
        timestep_spacing: "leading".
        clip_sample: False.
        set_alpha_to_one: False.
        rescale_betas_zero_snr: False (the paper's). True rescales the betas so that the last
            timestep is pure noise (zero terminal SNR; Lin et al. 2024, "Common Diffusion Noise
            Schedules and Sample Steps Are Flawed"). Without it `abar` at t=999 is 0.0047, so a
            v-prediction sample from t=999 keeps `sqrt(abar) = 0.068` of the starting noise in its
            x0 estimate: invisible for a unit-variance latent, but larger than the whole signal for
            a small residual target. Needs "v_prediction" or "sample" (epsilon cannot give x0 at
            zero SNR).
    """

    num_train_timesteps: int = 1000
    beta_start: float = 0.00085
    beta_end: float = 0.012
    beta_schedule: str = "scaled_linear"
    prediction_type: str = "epsilon"
    steps_offset: int = 1
    timestep_spacing: str = "leading"
    clip_sample: bool = False
    set_alpha_to_one: bool = False
    rescale_betas_zero_snr: bool = False

    def __post_init__(self) -> None:
        if self.timestep_spacing not in ("leading", "trailing", "linspace"):
            raise ConfigError(
                f"`scheduler.timestep_spacing` is {self.timestep_spacing!r}; expected 'leading' "
                "(the paper's), 'trailing' or 'linspace'."
            )
        if self.prediction_type not in PREDICTION_TYPES:
            raise ConfigError(
                f"`scheduler.prediction_type` is {self.prediction_type!r}; expected one of "
                f"{list(PREDICTION_TYPES)}."
            )
        if self.rescale_betas_zero_snr and self.prediction_type == "epsilon":
            raise ConfigError(
                "`scheduler.rescale_betas_zero_snr` is true with `scheduler.prediction_type` "
                "'epsilon'; at zero terminal SNR a noise prediction carries no information about "
                "the image. Use 'v_prediction' (or 'sample'), or set rescale_betas_zero_snr false."
            )

    def to_diffusers(self) -> dict[str, Any]:
        """Keyword arguments for `DDIMScheduler(**kwargs)` (other schedulers ignore unknown keys)."""
        return dataclasses.asdict(self)


@dataclass(frozen=True, kw_only=True)
class ModelConfig:
    """Everything needed to build a Neural Gaffer model.

    Attributes:
        name: preset name or a free label.
        resolution: image side length in pixels (256 for the released checkpoint).
        unet: denoiser shapes; `unet.sample_size` must equal `resolution / vae.downsampling_factor`.
        vae: autoencoder shapes.
        image_encoder: CLIP vision tower shapes; `projection_dim` must equal `unet.cross_attention_dim`.
        scheduler: noise schedule.
        residual: what is diffused. False (the paper, the released checkpoint): the target image's
            latent. True (gaffer-tiny): the target's latent minus the input image's latent, so the
            model only has to learn what the lighting changes; sampling adds the input's latent back
            before decoding (`NeuralGafferModel.diffusion_target` / `decodable_latents`).
        hints: False (the paper, the released checkpoint): the UNet input is `[z_t, E(x), E(E_H),
            E(E_L)]`. True (gaffer-tiny): 12 radiance-hint channels follow (`gaffer_diffusion.hints`,
            after DiLightNet): a white diffuse and two glossy renders of the input's silhouette
            normals under the target light, and the normals, computed from the input's mask and the
            lighting maps on every path; `unet.in_channels` is then 16 + 12.
        residual_space: with `residual`, what is subtracted. "display" (gaffer-tiny <= 0.4): the
            target's pixels minus the input's. "log_linear" (gaffer-tiny 0.5, pixel space only): the
            log of the target's linear radiance over the input's, a change of shading applied to
            the input in linear light, so the input's edges and texture are kept by construction
            (output = (input + eps) x exp(ratio) - eps).
        hint_geometry: with `hints`, where their normals come from: "silhouette" (the dome, 12
            channels) or "estimated" (the learned estimator, plus the de-lit ratio: 15 channels;
            `gaffer_diffusion.hints`).

    Raises:
        ConfigError: when the parts are inconsistent.

    Example:
        >>> cfg = get_preset("tiny")
        >>> cfg.latent_size, cfg.unet.in_channels
        (8, 16)
    """

    name: str
    resolution: int = 256
    unet: UNetConfig = field(default_factory=UNetConfig)
    vae: VAEConfig = field(default_factory=VAEConfig)
    image_encoder: ImageEncoderConfig = field(default_factory=ImageEncoderConfig)
    scheduler: SchedulerConfig = field(default_factory=SchedulerConfig)
    residual: bool = False
    hints: bool = False
    residual_space: ResidualSpace = "display"
    hint_geometry: HintGeometry = "silhouette"

    def __post_init__(self) -> None:
        if self.residual_space not in ("display", "log_linear"):
            raise ConfigError(
                f"`residual_space` is {self.residual_space!r}; expected 'display' or 'log_linear'."
            )
        if self.residual_space == "log_linear" and self.vae.kind != "pixel":
            raise ConfigError(
                "`residual_space` 'log_linear' needs a pixel-space model (`vae.kind` 'pixel'): a "
                "latent has no linear radiance; use 'display'."
            )
        if self.hint_geometry not in ("silhouette", "estimated"):
            raise ConfigError(
                f"`hint_geometry` is {self.hint_geometry!r}; expected 'silhouette' or 'estimated'."
            )
        factor = self.vae.downsampling_factor
        if self.resolution <= 0 or self.resolution % factor:
            raise ConfigError(
                f"`resolution` is {self.resolution}; it must be a positive multiple of the VAE "
                f"downsampling factor {factor}."
            )
        if self.unet.sample_size != self.resolution // factor:
            raise ConfigError(
                f"`unet.sample_size` is {self.unet.sample_size} but `resolution` {self.resolution} / "
                f"{factor} = {self.resolution // factor}. Use `ModelConfig.with_resolution(...)`."
            )
        expected_in = LATENT_CHANNELS * (1 + CONDITIONING_LATENTS) + self.hint_channels
        if self.unet.in_channels != expected_in:
            hint_text = f" + {self.hint_channels} hint channels" if self.hints else ""
            raise ConfigError(
                f"`unet.in_channels` is {self.unet.in_channels}, expected {expected_in} "
                f"([z_t, E(image), E(HDR), E(LDR)], 4 channels each{hint_text})."
            )
        if self.vae.latent_channels != LATENT_CHANNELS:
            raise ConfigError(f"`vae.latent_channels` is {self.vae.latent_channels}, expected 4.")
        if self.image_encoder.projection_dim != self.unet.cross_attention_dim:
            raise ConfigError(
                f"`image_encoder.projection_dim` ({self.image_encoder.projection_dim}) must equal "
                f"`unet.cross_attention_dim` ({self.unet.cross_attention_dim}): the CLIP embedding is "
                "the cross-attention context."
            )

    @property
    def hint_channels(self) -> int:
        """Radiance-hint channels after the conditioning latents (0 without `hints`)."""
        if not self.hints:
            return 0
        return ESTIMATED_HINT_CHANNELS if self.hint_geometry == "estimated" else HINT_CHANNELS

    @property
    def latent_size(self) -> int:
        """Latent side length h = w = resolution / 8."""
        return self.resolution // self.vae.downsampling_factor

    def with_resolution(self, resolution: int) -> "ModelConfig":
        """The same networks at another image size (the UNet is fully convolutional)."""
        factor = self.vae.downsampling_factor
        unet = dataclasses.replace(self.unet, sample_size=resolution // max(factor, 1))
        vae = dataclasses.replace(self.vae, sample_size=resolution)
        return dataclasses.replace(self, resolution=resolution, unet=unet, vae=vae)


def _tiny() -> ModelConfig:
    return ModelConfig(
        name="tiny",
        resolution=64,
        unet=UNetConfig(
            sample_size=8,
            block_out_channels=(32, 64),
            layers_per_block=1,
            down_block_types=("CrossAttnDownBlock2D", "DownBlock2D"),
            up_block_types=("UpBlock2D", "CrossAttnUpBlock2D"),
            attention_head_dim=8,
            cross_attention_dim=32,
            norm_num_groups=8,
        ),
        vae=VAEConfig(
            block_out_channels=(8, 8, 16, 16),
            layers_per_block=1,
            norm_num_groups=8,
            sample_size=64,
        ),
        image_encoder=ImageEncoderConfig(
            hidden_size=32,
            intermediate_size=37,
            num_hidden_layers=2,
            num_attention_heads=4,
            image_size=32,
            patch_size=8,
            projection_dim=32,
        ),
    )


GAFFER_TINY_CHANNELS: tuple[int, ...] = (16, 32, 64, 128)
"""UNet channels per level of `"gaffer-tiny"` (128, 64, 32, 16 px)."""

GAFFER_TINY_RESOLUTION = 128
"""Image side of `"gaffer-tiny"` 0.3 (0.1-0.2 were 64 px)."""


def _gaffer_tiny() -> ModelConfig:
    tiny = _tiny()
    res = GAFFER_TINY_RESOLUTION
    return ModelConfig(
        name="gaffer-tiny",
        resolution=res,
        unet=UNetConfig(
            sample_size=res,
            in_channels=LATENT_CHANNELS * (1 + CONDITIONING_LATENTS) + HINT_CHANNELS,
            block_out_channels=GAFFER_TINY_CHANNELS,
            layers_per_block=1,
            # attention only at 16x16 (and the mid block): at 32x32 it would cost more than the
            # convolutions of the whole UNet on a CPU
            down_block_types=("DownBlock2D", "DownBlock2D", "DownBlock2D", "CrossAttnDownBlock2D"),
            up_block_types=("CrossAttnUpBlock2D", "UpBlock2D", "UpBlock2D", "UpBlock2D"),
            attention_head_dim=4,
            cross_attention_dim=32,
            norm_num_groups=8,
        ),
        # scaling 5: the residual target (below) has std ~0.2 on the training renders ([-1, 1]
        # pixels); x5 brings it to ~1, the variance the noise schedule assumes (as SD's 0.18215
        # does for its latents).
        vae=VAEConfig(kind="pixel", scaling_factor=5.0, sample_size=res),
        image_encoder=tiny.image_encoder,
        # v-prediction: with epsilon in pixel space a young model's x0 = (z - sqrt(1 - abar) eps) /
        # sqrt(abar) amplifies its noise error ~14x at the first DDIM step and samples stay noise.
        # "trailing" spacing: sampling starts at t=999 whatever the step count. Zero terminal SNR:
        # at t=999 x0 = -v exactly, so the suggested one-step sample is the model's mean estimate.
        scheduler=SchedulerConfig(
            prediction_type="v_prediction",
            timestep_spacing="trailing",
            rescale_betas_zero_snr=True,
        ),
        # diffuse target - input: a model that has learnt nothing yet returns the input, not noise
        residual=True,
        # radiance hints (gaffer_diffusion.hints): shape and light transport a 3M-parameter model
        # cannot learn from a few hundred CPU-rendered objects
        hints=True,
    )


PRESETS = _choices.PRESETS


def get_preset(name: _PresetArg) -> ModelConfig:
    """A preset `ModelConfig` by name.

    Args:
        name: one of `PRESETS`.

    Raises:
        ConfigError: when `name` is unknown.

    Example:
        >>> get_preset("neural-gaffer-256").unet.block_out_channels
        (320, 640, 1280, 1280)
    """
    if name == "neural-gaffer-256":
        return ModelConfig(name=name)
    if name == "neural-gaffer-512":
        return dataclasses.replace(
            ModelConfig(name="neural-gaffer-256").with_resolution(512), name=name
        )
    if name == "tiny":
        return _tiny()
    if name == "gaffer-tiny":
        return _gaffer_tiny()
    raise ConfigError(f"`name` is {name!r}; expected one of {list(PRESETS)}.")
