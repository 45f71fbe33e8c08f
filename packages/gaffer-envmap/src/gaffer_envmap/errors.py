"""Errors raised by gaffer-envmap.

Every error names the argument at fault and says how to fix it. Concrete errors also subclass a builtin
(`ValueError`, `OSError`, `ImportError`) so callers that do not know gaffer still catch them sensibly.
"""


class GafferError(Exception):
    """Base class of every gaffer error, in all four packages (defined once, here in the leaf).

    `except gaffer_envmap.errors.GafferError` catches what any gaffer package raises on purpose.
    """

    def diagnostics(self) -> str:
        """A human-readable explanation for the command line (the message by default)."""
        return str(self)


class GafferEnvmapError(GafferError):
    """Base class of every gaffer-envmap error."""


class ShapeError(GafferEnvmapError, ValueError):
    """An array has the wrong shape. Carries `argument`, `actual` and `expected` (as strings).

    The one shape error of gaffer: gaffer-data's, gaffer-diffusion's and gaffer-nerf's `ShapeError`
    subclass it (and their own base), so `except gaffer_envmap.ShapeError` catches all of them.
    """

    def __init__(self, argument: str, actual: object, expected: str, fix: str = "") -> None:
        self.argument = argument
        self.actual = str(actual)
        self.expected = expected
        msg = f"`{argument}` has shape {self.actual}, expected {expected}."
        super().__init__(f"{msg} {fix}".strip())


class NonFiniteError(GafferEnvmapError, ValueError):
    """An environment map holds NaN, Inf or negative radiance and the sanitize policy is "raise"."""


class PoseError(GafferEnvmapError, ValueError):
    """A camera matrix is malformed (wrong shape, not a rotation, non-finite)."""


class ConventionError(GafferEnvmapError, ValueError):
    """An unknown convention name or an impossible conversion between conventions."""


class EnvmapReadError(GafferEnvmapError, OSError):
    """A file could not be read as an environment map (missing, truncated, corrupt, unsupported)."""


class EnvmapWriteError(GafferEnvmapError, OSError):
    """A file could not be written; the destination was left untouched."""


class HalfOverflowError(GafferEnvmapError, ValueError):
    """A half-float (fp16) write would overflow 65504 and the overflow policy is "raise"."""


class MissingDependencyError(GafferEnvmapError, ImportError):
    """An optional dependency is needed for this call; the message holds the exact pip command."""


class OutputPathError(GafferEnvmapError, ValueError):
    """A command's output path cannot be written as asked: a file where a folder is expected (or the
    reverse, also for a file or folder the command writes inside its output folder), an unwritable
    place, or a format whose writer is not installed. Raised before any work."""


class ParameterError(GafferEnvmapError, ValueError):
    """A lighting parameter is out of range or inconsistent (a sun elevation of 120 degrees, a
    turbidity of 0, a time without a UTC offset); the message names it and the valid range."""


class EnvmapSourceError(GafferEnvmapError, ValueError):
    """A lighting source (`gaffer_envmap.sources`, entry-point group `gaffer.envmap_sources`) is
    unknown, failed to load, lacks what was asked of it, was given an option it does not take, failed
    while running, or returned a map that is not a finite, non-negative 2:1 lat-long map. The message
    names the source and, for an unknown one, the installed ones."""
