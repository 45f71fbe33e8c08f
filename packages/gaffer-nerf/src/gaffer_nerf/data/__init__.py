"""Multi-view inputs: NeRF-Synthetic `transforms_*.json` folders and gaffer-data render sets."""

from gaffer_nerf.data.gaffer_data import load_lighting_envmap, read_gaffer_data_object
from gaffer_nerf.data.transforms import (
    LightingInfo,
    MultiViewScene,
    ViewSet,
    composite_white,
    read_rgba,
    read_transforms_folder,
    read_transforms_split,
)

__all__ = [
    "LightingInfo",
    "MultiViewScene",
    "ViewSet",
    "composite_white",
    "load_lighting_envmap",
    "read_gaffer_data_object",
    "read_rgba",
    "read_transforms_folder",
    "read_transforms_split",
]
