"""Input-layer surgery: Zero123's 8-channel `conv_in` -> Neural Gaffer's 16 channels."""

import torch
from diffusers.models.unets.unet_2d_condition import UNet2DConditionModel

from gaffer_diffusion.errors import ConfigError


def _pair(size: tuple[int, ...]) -> tuple[int, int]:
    """A `Conv2d`'s `(h, w)` size attribute (torch types it `tuple[int, ...]`) as the pair it is."""
    h, w = size
    return h, w


@torch.no_grad()
def expand_conv_in(unet: UNet2DConditionModel, in_channels: int = 16) -> UNet2DConditionModel:
    """Widen the UNet's first convolution in place, as Neural Gaffer does (official implementation §1).

    Weights for the existing input channels are copied, the new channels are zero-initialised (so the
    widened UNet computes exactly what it did before when the new inputs are zero) and the bias is
    copied. Unlike the authors' code, `unet.config.in_channels` is updated, so a saved config is true.

    Args:
        unet: a UNet with `conv_in.in_channels <= in_channels` (8 for Zero123-XL).
        in_channels: the new number of input channels (16).

    Returns:
        The same `unet`, modified.

    Raises:
        ConfigError: when `in_channels` is smaller than the current number of input channels.
    """
    old = unet.conv_in
    if in_channels < old.in_channels:
        raise ConfigError(
            f"`in_channels` is {in_channels}, smaller than the UNet's current {old.in_channels}."
        )
    if in_channels == old.in_channels:
        return unet
    new = torch.nn.Conv2d(
        in_channels,
        old.out_channels,
        kernel_size=_pair(old.kernel_size),
        stride=_pair(old.stride),
        padding=old.padding if isinstance(old.padding, str) else _pair(old.padding),
        device=old.weight.device,
        dtype=old.weight.dtype,
    )
    new.weight.zero_()
    new.weight[:, : old.in_channels] = old.weight
    if old.bias is not None and new.bias is not None:
        new.bias.copy_(old.bias)
    unet.conv_in = new
    unet.register_to_config(in_channels=in_channels)
    return unet
