"""Neural Gaffer nodes for ComfyUI: relight an object photo under an HDR environment map.

`NODE_CLASS_MAPPINGS` and `NODE_DISPLAY_NAME_MAPPINGS` are what ComfyUI reads. Nothing here imports
ComfyUI (`comfy`, `folder_paths`, `nodes`): the pack imports and runs without it, and uses ComfyUI's
folders, device and progress bar only when it runs inside it (`_boundary`). The heavy gaffer libraries
load when a node first runs.
"""

from ._version import __version__
from .envmap_nodes import NeuralGafferLoadEnvmap, NeuralGafferRotateEnvmap, NeuralGafferSky
from .errors import NodeInputError
from .insert_node import NeuralGafferInsert
from .relight_nodes import NeuralGafferLoadModel, NeuralGafferRelight, NeuralGafferTurntable
from .types import GAFFER_ENVMAP, GAFFER_MODEL, GafferEnvmap, GafferModel

NODE_CLASS_MAPPINGS: dict[str, type] = {
    "NeuralGafferLoadModel": NeuralGafferLoadModel,
    "NeuralGafferLoadEnvmap": NeuralGafferLoadEnvmap,
    "NeuralGafferRotateEnvmap": NeuralGafferRotateEnvmap,
    "NeuralGafferSky": NeuralGafferSky,
    "NeuralGafferRelight": NeuralGafferRelight,
    "NeuralGafferTurntable": NeuralGafferTurntable,
    "NeuralGafferInsert": NeuralGafferInsert,
}
"""Node id -> class. Every id starts with `NeuralGaffer` (ComfyUI-Gaffer's ids are unprefixed)."""

NODE_DISPLAY_NAME_MAPPINGS: dict[str, str] = {
    "NeuralGafferLoadModel": "Neural Gaffer: Load Model",
    "NeuralGafferLoadEnvmap": "Neural Gaffer: Load HDR Environment Map",
    "NeuralGafferRotateEnvmap": "Neural Gaffer: Rotate Environment Map",
    "NeuralGafferSky": "Neural Gaffer: Sky from Words",
    "NeuralGafferRelight": "Neural Gaffer: Relight",
    "NeuralGafferTurntable": "Neural Gaffer: Turntable",
    "NeuralGafferInsert": "Neural Gaffer: Insert Object",
}

__all__ = [
    "GAFFER_ENVMAP",
    "GAFFER_MODEL",
    "NODE_CLASS_MAPPINGS",
    "NODE_DISPLAY_NAME_MAPPINGS",
    "GafferEnvmap",
    "GafferModel",
    "NeuralGafferInsert",
    "NeuralGafferLoadEnvmap",
    "NeuralGafferLoadModel",
    "NeuralGafferRelight",
    "NeuralGafferRotateEnvmap",
    "NeuralGafferSky",
    "NeuralGafferTurntable",
    "NodeInputError",
    "__version__",
]
