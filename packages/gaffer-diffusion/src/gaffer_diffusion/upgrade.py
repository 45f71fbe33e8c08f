"""Turn a gaffer-tiny <= 0.4 model (dome hints, display-space residual) into the starting point of
0.5 (estimated-geometry hints, log-linear residual), keeping what it has learnt.

The UNet's first convolution gains the three de-lit-ratio hint channels, zero-initialised
(`expand_conv_in`: they are appended after the 12 hint channels, where `relighting_hints` puts them),
and the config switches `hint_geometry` to "estimated" and `residual_space` to "log_linear" with a
new target scale. Fine-tuning (`configs/gaffer-tiny-stage4.json`) then teaches it the new target.

    python -m gaffer_diffusion.upgrade SRC DST --scaling-factor 1.5
"""

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

from gaffer_diffusion.configs import CONDITIONING_LATENTS, LATENT_CHANNELS
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.hints import ESTIMATED_HINT_CHANNELS
from gaffer_diffusion.loading import load_pretrained, save_pretrained
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.models.pixel import PixelAutoencoder
from gaffer_diffusion.models.surgery import expand_conv_in
from gaffer_diffusion.suggested import read_suggested_sampling

__all__ = ["to_estimated_geometry"]

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


def main(argv: list[str] | None = None) -> int:
    """`python -m gaffer_diffusion.upgrade SRC DST --scaling-factor S`."""
    parser = argparse.ArgumentParser(prog="python -m gaffer_diffusion.upgrade")
    parser.add_argument("src", type=Path, help="a gaffer-tiny <= 0.4 model folder")
    parser.add_argument("dst", type=Path, help="where the upgraded model is written")
    parser.add_argument("--scaling-factor", type=float, required=True)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        model = load_pretrained(args.src).model
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
