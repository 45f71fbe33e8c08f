"""Exact lighting augmentation: horizontal flips and yaw steps (whole-pixel rolls).

The paper grows 1,870 HDRIs to about 30K by flips and yaw rotations (reference section 4.9: 2 flips x 8
yaws of 45 degrees). With We divisible by the number of steps, both are permutations of pixels: lossless,
and power-preserving to the last bit.

Sign convention (shared with `rotate_to_camera(spin_deg=...)`): a positive yaw turns the light
counter-clockwise about world up, seen from above. In the Blender layout u grows as phi falls, so that is a
roll of the image to the LEFT.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import GafferEnvmapError

if TYPE_CHECKING:
    import torch


def flip_horizontal(env: EnvironmentMap) -> EnvironmentMap:
    """Mirror the map left-right: a reflection through the plane holding the u = 0 and u = 0.5 directions.

    (For the Blender convention that is the world x-z plane: y -> -y.)
    """
    return env.with_radiance(env.radiance_linear[:, ::-1, :])


def yaw_roll(env: EnvironmentMap, step: int, num_steps: int) -> EnvironmentMap:
    """Turn the light by `step / num_steps` of a full turn about world up (counter-clockwise from above).

    Raises:
        GafferEnvmapError: when `num_steps` does not divide the width (the roll would not be exact).
    """
    if num_steps < 1 or env.width % num_steps:
        raise GafferEnvmapError(
            f"`num_steps`={num_steps} must be >= 1 and divide the map width {env.width} for an exact roll; "
            "resize with `resize_conservative` to a width divisible by it."
        )
    shift = -(step % num_steps) * (env.width // num_steps)
    return env.with_radiance(np.roll(env.radiance_linear, shift, axis=1))


def mirror_camera_x(maps_cam: "torch.Tensor") -> "torch.Tensor":
    """Camera-frame maps (`neural-gaffer-camera` layout) of the scene mirrored left-right in the image.

    Flipping an input image horizontally mirrors the scene in camera x (x -> -x). In this layout the
    centre column is camera right, so the mirror maps u -> 0.5 - u: a horizontal flip plus a roll by
    half the width, exact (a permutation of columns) for an even width. Used for mirror augmentation
    in training and mirror test-time averaging: `relight(flip(x), mirror_camera_x(L))` flipped back
    estimates the same image as `relight(x, L)`.

    Args:
        maps_cam: `[..., He, We]` camera-frame lat-long maps, channels first (e.g. `[B, 3, H, W]`
            LDR/HDR encodings), any dtype or device.

    Raises:
        GafferEnvmapError: on an odd width (the half-width roll would not be exact).
    """
    width = int(maps_cam.shape[-1])
    if width % 2:
        raise GafferEnvmapError(
            f"`maps_cam` has odd width {width}; the camera-x mirror needs an even width (resize the "
            "maps to an even width first)."
        )
    return maps_cam.flip(-1).roll(width // 2, dims=-1)


@dataclass(frozen=True)
class AugmentSpec:
    """One augmentation: an optional flip, then a yaw of `yaw_step / num_steps` of a turn."""

    flip: bool = False
    yaw_step: int = 0
    num_steps: int = 1

    @property
    def yaw_deg(self) -> float:
        """Counter-clockwise yaw about world up, in degrees."""
        return 360.0 * self.yaw_step / self.num_steps

    @property
    def tag(self) -> str:
        """Short file-name-safe label, e.g. `f1_y3of8`."""
        return f"f{int(self.flip)}_y{self.yaw_step}of{self.num_steps}"

    def apply(self, env: EnvironmentMap) -> EnvironmentMap:
        """The augmented map."""
        out = flip_horizontal(env) if self.flip else env
        return yaw_roll(out, self.yaw_step, self.num_steps) if self.yaw_step else out


def augment_specs(flips: bool = True, yaw_steps: int = 8) -> list[AugmentSpec]:
    """All combinations: (1 or 2 flips) x `yaw_steps` yaws; the identity comes first."""
    return [
        AugmentSpec(flip=f, yaw_step=k, num_steps=yaw_steps)
        for f in ((False, True) if flips else (False,))
        for k in range(yaw_steps)
    ]


def augment_pool(
    env: EnvironmentMap, flips: bool = True, yaw_steps: int = 8
) -> list[tuple[AugmentSpec, EnvironmentMap]]:
    """Every augmented copy of one map, with its spec (2 x 8 = 16 by default, as the paper)."""
    return [(spec, spec.apply(env)) for spec in augment_specs(flips, yaw_steps)]
