"""Errors raised by gaffer-diffusion.

Every error names the argument or file at fault and says how to fix it. Concrete errors also subclass a
builtin (`ValueError`, `FileNotFoundError`, `ImportError`, `RuntimeError`) so that callers that do not
know gaffer still catch them sensibly. Errors meant for the command line implement `diagnostics()`.
"""

from collections.abc import Sequence

from gaffer_envmap.errors import GafferError
from gaffer_envmap.errors import ShapeError as EnvmapShapeError


class GafferDiffusionError(GafferError):
    """Base class of every gaffer-diffusion error (`diagnostics()` comes from `gaffer_envmap.errors.GafferError`)."""


class ConfigError(GafferDiffusionError, ValueError):
    """A configuration value is invalid or two values are inconsistent."""


class ShapeError(GafferDiffusionError, EnvmapShapeError):
    """A tensor has the wrong shape. Carries `argument`, `actual` and `expected` (as strings).

    Defined once, in `gaffer_envmap.errors.ShapeError` (message and fields); this subclass adds the
    gaffer-diffusion base, so `except GafferDiffusionError` and `except gaffer_envmap.ShapeError` both catch it.
    """


class InputValueError(GafferDiffusionError, ValueError):
    """A tensor holds values outside the documented range (NaN, Inf, or outside [0, 1])."""


class NonFiniteOutputError(GafferDiffusionError, RuntimeError):
    """Sampling produced NaN or Inf. Raised instead of returning a silently broken image."""

    def __init__(self, stage: str, dtype: object, indices: Sequence[int]) -> None:
        self.stage = stage
        self.dtype = str(dtype)
        self.indices = tuple(int(i) for i in indices)
        super().__init__(
            f"Non-finite values (NaN/Inf) appeared in the {stage} for batch items {list(self.indices)} "
            f"while running in {self.dtype}. This is usually a half-precision overflow: rerun with "
            "`dtype=torch.float32` or `dtype=torch.bfloat16` (bf16 has the fp32 exponent range), or pass "
            '`nonfinite="retry_fp32"` to rerun the affected items in float32 automatically.'
        )


class CheckpointNotFoundError(GafferDiffusionError, FileNotFoundError):
    """A weights or config file is missing. Says which file, where it looked and how to get it."""

    def __init__(self, what: str, looked_in: Sequence[object], how_to_get: str) -> None:
        self.what = what
        self.looked_in = tuple(str(p) for p in looked_in)
        self.how_to_get = how_to_get
        where = "\n".join(f"  - {p}" for p in self.looked_in)
        super().__init__(f"Could not find {what}. Looked in:\n{where}\n{how_to_get}")


class CheckpointMismatchError(GafferDiffusionError, ValueError):
    """A state dict does not match the model (missing, unexpected or mis-shaped tensors)."""


class MissingDependencyError(GafferDiffusionError, ImportError):
    """An optional dependency is needed for this call; the message holds the exact pip command."""


class MetricUnavailableError(GafferDiffusionError, RuntimeError):
    """A metric cannot be computed here (e.g. no offline weights); the message says why."""


class DatasetError(GafferDiffusionError, ValueError):
    """An evaluation dataset is unusable (no pairs, a missing env map or image); says how to fix it."""
