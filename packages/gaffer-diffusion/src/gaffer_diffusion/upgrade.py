"""Turn a gaffer-tiny <= 0.4 model (dome hints, display-space residual) into the starting point of
0.5 (estimated-geometry hints, log-linear residual), keeping what it has learnt.

The UNet's first convolution gains the three de-lit-ratio hint channels, zero-initialised
(`expand_conv_in`: they are appended after the 12 hint channels, where `relighting_hints` puts them),
and the config switches `hint_geometry` to "estimated" and `residual_space` to "log_linear" with a
new target scale. Fine-tuning (`configs/gaffer-tiny-stage4.json`) then teaches it the new target.

`with_new_unet` starts a wider model from the same folder: a UNet of new channel
widths, randomly initialised from a seed, beside the folder's frozen image encoder, pixel autoencoder,
hints and residual target, which every later stage keeps. Stage 5's display-space loss then trains it
from nothing (`configs/gaffer-tiny-wide.json`); a wider UNet could not inherit the old weights.

    python -m gaffer_diffusion.upgrade SRC DST --scaling-factor 1.5
    python -m gaffer_diffusion.upgrade SRC DST --new-unet-channels 32,64,128,256 --seed 0
"""

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

import torch

from gaffer_diffusion.configs import CONDITIONING_LATENTS, LATENT_CHANNELS
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.hints import ESTIMATED_HINT_CHANNELS
from gaffer_diffusion.loading import load_pretrained, save_pretrained
from gaffer_diffusion.models.build import build_unet
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.models.pixel import PixelAutoencoder
from gaffer_diffusion.models.surgery import expand_conv_in
from gaffer_diffusion.suggested import read_suggested_sampling

__all__ = ["to_estimated_geometry", "with_new_unet"]

logger = logging.getLogger(__name__)


def to_estimated_geometry(model: NeuralGafferModel, *, scaling_factor: float) -> NeuralGafferModel:
    """A model with estimated-geometry hints and a log-linear residual target (see the module doc).

    Raises:
        ConfigError: the model is not a pixel-space residual model with dome hints, or the scale is
            not positive.
    """
    cfg = model.config
    if not (cfg.hints and cfg.residual and cfg.vae.kind == "pixel"):
        raise ConfigError("`model` must be a pixel-space residual model with hints (gaffer-tiny).")
    if cfg.hint_geometry != "silhouette":
        raise ConfigError("`model` already has estimated-geometry hints.")
    if not scaling_factor > 0:
        raise ConfigError(f"`scaling_factor` is {scaling_factor}; expected a positive number.")
    in_channels = LATENT_CHANNELS * (1 + CONDITIONING_LATENTS) + ESTIMATED_HINT_CHANNELS
    unet = expand_conv_in(model.unet, in_channels)
    vae = PixelAutoencoder(sample_size=cfg.vae.sample_size, scaling_factor=scaling_factor)
    config = dataclasses.replace(
        cfg,
        unet=dataclasses.replace(cfg.unet, in_channels=in_channels),
        vae=dataclasses.replace(cfg.vae, scaling_factor=scaling_factor),
        hint_geometry="estimated",
        residual_space="log_linear",
    )
    return NeuralGafferModel(config=config, unet=unet, vae=vae, image_encoder=model.image_encoder)


def with_new_unet(
    model: NeuralGafferModel, channels: tuple[int, ...], *, seed: int = 0
) -> NeuralGafferModel:
    """`model` with a new randomly initialised UNet of `channels` per level (see the module doc).

    Everything else of the UNet's config (inputs, blocks, attention) and the other modules are kept.
    The new UNet's weights depend only on its config and `seed` (torch's global RNG is restored).

    Raises:
        ConfigError: `channels` has another number of levels than the UNet, or a width that is not
            a positive multiple of the UNet's `norm_num_groups`.
    """
    unet_cfg = model.config.unet
    groups = unet_cfg.norm_num_groups
    if len(channels) != len(unet_cfg.block_out_channels):
        raise ConfigError(
            f"`channels` {channels} has {len(channels)} levels; the UNet has "
            f"{len(unet_cfg.block_out_channels)} ({unet_cfg.block_out_channels})."
        )
    if any(c <= 0 or c % groups for c in channels):
        raise ConfigError(
            f"`channels` {channels}: every width must be a positive multiple of the UNet's "
            f"norm_num_groups ({groups})."
        )
    new_cfg = dataclasses.replace(unet_cfg, block_out_channels=tuple(channels))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        unet = build_unet(new_cfg)
    config = dataclasses.replace(model.config, unet=new_cfg)
    return NeuralGafferModel(
        config=config, unet=unet.eval(), vae=model.vae, image_encoder=model.image_encoder
    )


def _channels(text: str) -> tuple[int, ...]:
    try:
        return tuple(int(c) for c in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected comma-separated integers, e.g. 32,64,128,256"
        ) from None


def main(argv: list[str] | None = None) -> int:
    """`python -m gaffer_diffusion.upgrade SRC DST (--scaling-factor S | --new-unet-channels C,...)`."""
    parser = argparse.ArgumentParser(prog="python -m gaffer_diffusion.upgrade")
    parser.add_argument("src", type=Path, help="a gaffer-tiny model folder")
    parser.add_argument("dst", type=Path, help="where the upgraded model is written")
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument(
        "--scaling-factor", type=float, help="0.4 -> 0.5: estimated hints, log-linear residual"
    )
    how.add_argument(
        "--new-unet-channels",
        type=_channels,
        help="a new random UNet of these widths per level (e.g. 32,64,128,256)",
    )
    parser.add_argument("--seed", type=int, help="seed of the new UNet (default 0)")
    args = parser.parse_args(argv)
    if args.seed is not None and args.new_unet_channels is None:
        parser.error("--seed seeds a new UNet: pass it with --new-unet-channels, or drop it")
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        model = load_pretrained(args.src).model
        if args.new_unet_channels is not None:
            upgraded = with_new_unet(model, args.new_unet_channels, seed=args.seed or 0)
        else:
            upgraded = to_estimated_geometry(model, scaling_factor=args.scaling_factor)
        # the sampling the source suggests (1 DDIM step, mirror mean, 75% framing) carries over
        save_pretrained(upgraded, args.dst, suggested=read_suggested_sampling(args.src))
    except ConfigError as exc:
        logger.error("error: %s", exc)
        return 2
    logger.info("upgraded model: %s", args.dst)
    return 0


if __name__ == "__main__":
    sys.exit(main())
