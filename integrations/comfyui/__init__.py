"""ComfyUI entry point of the Neural Gaffer node pack, for a copy of this folder in
`ComfyUI/custom_nodes/` (ComfyUI imports this file as a package and reads the two mappings). The
nodes live in `src/gaffer_comfyui/`, which `pip install` installs as `gaffer_comfyui` instead."""

from .src.gaffer_comfyui import NODE_CLASS_MAPPINGS, NODE_DISPLAY_NAME_MAPPINGS

__all__ = ["NODE_CLASS_MAPPINGS", "NODE_DISPLAY_NAME_MAPPINGS"]
