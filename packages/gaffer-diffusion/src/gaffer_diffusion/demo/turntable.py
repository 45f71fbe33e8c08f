"""The turntable: which bundled HDRI it spins, and its GIF (frames side by side, upscaled)."""

from typing import Any

import numpy as np

from gaffer_diffusion.errors import ConfigError

GIF_SCALE = 4
"""Nearest-neighbour upscale of the model-size turntable frames in the GIF, so that it is watchable."""


def _turntable_hdri(name: str | None) -> tuple[str, Any]:
    """The turntable's bundled HDRI (`DemoConfig.turntable_hdri`) and its map."""
    from gaffer_envmap import directionality
    from gaffer_envmap.bundled import bundled_hdris, read_bundled_hdri

    names = sorted(bundled_hdris())
    if name is not None:
        if name not in names:
            raise ConfigError(
                f"`turntable_hdri` (--turntable-hdri) is {name!r}; expected one of {names}."
            )
        return name, read_bundled_hdri(name)
    maps = {n: read_bundled_hdri(n) for n in names}
    best = max(names, key=lambda n: directionality(maps[n], about_up=True))
    return best, maps[best]


def _side_by_side(*images: np.ndarray, scale: int = GIF_SCALE) -> np.ndarray:
    row = np.concatenate(images, axis=1)
    return row.repeat(scale, axis=0).repeat(scale, axis=1)
