"""Environment-map augmentation on raw lat-long pixels (pure numpy, usable inside the bpy worker).

This is the twin of `gaffer_envmap.augment.AugmentSpec(flip, yaw_step, num_steps).apply`, which the
worker cannot import (gaffer-envmap pulls in torch, which we keep out of Blender processes). A test
checks that both agree pixel for pixel whenever gaffer-envmap provides `augment`.
"""

import numpy as np

from gaffer_data.errors import ConfigError


def augment_latlong(pixels: np.ndarray, *, flip: bool, yaw_step: int, num_steps: int) -> np.ndarray:
    """Mirror and/or roll a lat-long map along its columns (the azimuth axis).

    Both operations act on columns only, so they are exact (no resampling) and independent of the row
    order (Blender stores rows bottom-up, EXR files top-down).

    Args:
        pixels: `[He, We, C]` pixels.
        flip: mirror the columns first (azimuth -> -azimuth about the map centre).
        yaw_step: then turn the light by `yaw_step / num_steps` of a turn counter-clockwise about world
            up (seen from above), which in Blender's layout (u grows as the azimuth falls) is a roll of
            the columns to the LEFT by `yaw_step * We / num_steps`.
        num_steps: steps per full turn; `We` must be divisible by it.

    Returns:
        A new `[He, We, C]` array.

    Raises:
        ConfigError: `We` is not divisible by `num_steps`.
    """
    width = pixels.shape[1]
    if num_steps < 1 or width % num_steps:
        raise ConfigError(
            f"`num_steps`={num_steps} does not divide the map width {width}; pick "
            "`augment.yaw_steps` dividing every pool map's width (e.g. 8 for 1024-wide maps)."
        )
    out = pixels[:, ::-1] if flip else pixels
    shift = -(yaw_step % num_steps) * (width // num_steps)
    return np.ascontiguousarray(np.roll(out, shift, axis=1) if shift else out)
