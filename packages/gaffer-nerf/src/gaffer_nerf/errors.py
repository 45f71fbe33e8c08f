"""Errors raised by gaffer-nerf.

Every error names the argument or file at fault and says how to fix it. Concrete errors also subclass a
builtin (`ValueError`, `FileNotFoundError`, `ImportError`, `RuntimeError`) so callers that do not know
gaffer still catch them. Errors meant for the command line implement `diagnostics()`.
"""

from gaffer_envmap.errors import GafferError
from gaffer_envmap.errors import ShapeError as EnvmapShapeError


class GafferNerfError(GafferError):
    """Base class of every gaffer-nerf error (`diagnostics()` comes from `gaffer_envmap.errors.GafferError`)."""


class ConfigError(GafferNerfError, ValueError):
    """A configuration value is invalid or two values are inconsistent."""


class ShapeError(GafferNerfError, EnvmapShapeError):
    """A tensor has the wrong shape. Carries `argument`, `actual` and `expected` (as strings).

    Defined once, in `gaffer_envmap.errors.ShapeError` (message and fields); this subclass adds the
    gaffer-nerf base, so `except GafferNerfError` and `except gaffer_envmap.ShapeError` both catch it.
    """


class CameraError(GafferNerfError, ValueError):
    """Cameras are unusable: NaN/Inf poses, non-rotations, non-positive focal lengths, no baseline."""


class DatasetError(GafferNerfError, ValueError):
    """A multi-view folder is malformed (missing keys, images, splits); says what to fix."""


class DatasetNotFoundError(GafferNerfError, FileNotFoundError):
    """A dataset file (transforms json, image, env map) does not exist."""


class CheckpointError(GafferNerfError, ValueError):
    """A radiance-field checkpoint is missing, of another class or of an incompatible version."""


class MissingDependencyError(GafferNerfError, ImportError):
    """An optional dependency is needed for this call; the message holds the exact pip command."""


class NonFiniteError(GafferNerfError, RuntimeError):
    """A loss or a rendered image became NaN/Inf; the message names the stage and iteration."""
