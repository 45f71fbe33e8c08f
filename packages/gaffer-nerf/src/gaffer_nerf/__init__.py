"""gaffer-nerf: skeleton only. Nothing is implemented yet; see the project's open issues."""

from gaffer_nerf._version import __version__

__all__ = ["__version__"]
