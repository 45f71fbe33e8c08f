"""Find and repair NaN, ±Inf and negative radiance in an environment map.

A single NaN propagates through every blur, resize and rotation, and a single Inf turns an energy
normalisation into zeros, so maps are checked once, on load (the policy is an argument of
`gaffer_envmap.io.read_envmap`). Counts are per value (per channel), not per pixel.
"""

import dataclasses
import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, TypeGuard, assert_never

import numpy as np

from gaffer_envmap.errors import NonFiniteError

__all__ = [
    "SANITIZE_POLICIES",
    "TINY_NEGATIVE_FRACTION",
    "TINY_NEGATIVE_RELATIVE",
    "SanitizePolicy",
    "SanitizeReport",
    "add_sanitize_argument",
    "sanitize",
    "sanitize_flag_refusal",
    "sanitize_help",
]

logger = logging.getLogger(__name__)

SanitizePolicy = Literal["raise", "strict", "zero", "clamp"]
"""What `sanitize` does with NaN, +Inf, -Inf and negative values.

- "raise" (the default everywhere): tiny negatives, the noise of lossy EXR compression (DWAB/PIZ
  ringing round dark pixels; 7 of the 8 bundled HDRIs hold some), are set to 0 with an INFO line;
  anything else (NaN, ±Inf, a substantial negative) raises `NonFiniteError` naming the counts.
  "Tiny": every negative has |v| <= `TINY_NEGATIVE_RELATIVE` x the map's mean |radiance| and they are
  at most `TINY_NEGATIVE_FRACTION` of its values.
- "strict": raise `NonFiniteError` on any NaN, ±Inf or negative value (nothing is changed).
- "zero": NaN, ±Inf and negatives become 0.
- "clamp": NaN, -Inf and negatives become 0; +Inf becomes the largest finite value in the map
  (0 when there is none), which keeps a clipped sun bright instead of deleting it.
"""

_POLICIES = ("raise", "strict", "zero", "clamp")
SANITIZE_POLICIES: tuple[SanitizePolicy, ...] = _POLICIES
"""The choices of every gaffer CLI's `--sanitize` flag (one source for all four packages)."""

_POLICY_HELP = {
    "raise": "sets tiny negatives from lossy compression to 0 with an INFO line and refuses "
    "anything else",
    "strict": "refuses any",
    "zero": "sets all to 0",
    "clamp": "sets all to 0 but +Inf, which becomes the brightest finite value",
}


def sanitize_help(default: SanitizePolicy = "raise", *, what: str = "") -> str:
    """Help text of a `--sanitize` flag whose default is `default` (the same words on every CLI).

    `what` is an optional prefix saying what the flag applies to (e.g. "reported, not applied: ").
    """
    parts = [
        f"'{p}'{' (default)' if p == default else ''} {_POLICY_HELP[p]}" for p in SANITIZE_POLICIES
    ]
    return f"{what}NaN/Inf/negative env-map pixels: " + "; ".join(parts)


def add_sanitize_argument(
    parser: "argparse.ArgumentParser | argparse._ArgumentGroup",
    default: SanitizePolicy = "raise",
    *,
    what: str = "",
) -> None:
    """Add the `--sanitize` flag (choices `SANITIZE_POLICIES`, help `sanitize_help`) to `parser`."""
    parser.add_argument(
        "--sanitize",
        choices=SANITIZE_POLICIES,
        default=default,
        help=sanitize_help(default, what=what),
    )


def sanitize_flag_refusal(error: Exception, policy: str) -> str:
    """A `NonFiniteError` of `sanitize`/`read_envmap` said as a command line says it: one line naming
    `--sanitize` and its values instead of the API's `sanitize=` keyword.

    Example:
        >>> from gaffer_envmap.errors import NonFiniteError
        >>> sanitize_flag_refusal(NonFiniteError('`a.exr` holds 1 NaN value(s). Pass `sanitize="zero"`'), "raise")
        '`a.exr` holds 1 NaN value(s). Pass `--sanitize zero` (set them to 0) or `--sanitize clamp` (+Inf -> brightest finite value, the rest -> 0), or repair the file (`--sanitize raise` refused it).'
    """
    what = str(error).split(" Pass `sanitize=")[0]
    return (
        f"{what} Pass `--sanitize zero` (set them to 0) or `--sanitize clamp` (+Inf -> brightest "
        f"finite value, the rest -> 0), or repair the file (`--sanitize {policy}` refused it)."
    )


TINY_NEGATIVE_RELATIVE = 0.05
"""Largest |negative| that counts as compression noise, relative to the map's mean |radiance|. The
bundled maps' worst is 0.0145 (night: -0.0017 against a mean of 0.116); a real sign error or a
subtracted map is of the order of the mean itself."""

TINY_NEGATIVE_FRACTION = 0.01
"""At most this fraction of the values may be tiny negatives (the bundled maps: <= 0.06 %)."""


@dataclass(frozen=True, kw_only=True)
class SanitizeReport:
    """What `sanitize` found and did. Counts are per value (one pixel can count three times).

    Attributes:
        num_nan: NaN values found.
        num_posinf: +Inf values found.
        num_neginf: -Inf values found.
        num_negative: finite values < 0 found (-0.0 is not negative).
        policy: the policy that was applied.
        posinf_replacement: the value +Inf became under "clamp" (0.0 under "zero"), else None.
    """

    num_nan: int
    num_posinf: int
    num_neginf: int
    num_negative: int
    policy: SanitizePolicy
    posinf_replacement: float | None = None
    tiny_negatives_clamped: bool = False

    @property
    def num_bad(self) -> int:
        """Total number of values that were (or, under "raise", would be) changed."""
        return self.num_nan + self.num_posinf + self.num_neginf + self.num_negative

    @property
    def clean(self) -> bool:
        """True when the input held no NaN, Inf or negative value."""
        return self.num_bad == 0

    def describe(self) -> str:
        """A one-line summary such as "2 NaN, 1 +Inf, 0 -Inf, 5 negative"."""
        return (
            f"{self.num_nan} NaN, {self.num_posinf} +Inf, {self.num_neginf} -Inf, "
            f"{self.num_negative} negative"
        )


if TYPE_CHECKING:
    import argparse

    _PolicyArg = SanitizePolicy
else:  # at run time any str reaches `sanitize`, which refuses an unknown one with a ValueError
    _PolicyArg = str


def _is_policy(policy: str) -> TypeGuard[SanitizePolicy]:
    return policy in _POLICIES


def sanitize(
    radiance: np.ndarray, policy: _PolicyArg = "raise", *, name: str = "radiance"
) -> tuple[np.ndarray, SanitizeReport]:
    """Check an array for NaN, ±Inf and negative values and apply `policy`.

    Args:
        radiance: `[..., C]` (any shape) float array, typically `[He, We, 3]` linear radiance.
        policy: "raise", "strict", "zero" or "clamp" (see `SanitizePolicy`).
        name: how to call the array in error messages (e.g. a file path).

    Returns:
        `(clean, report)`: `clean` has the shape and dtype of `radiance` (a new array when anything
        was replaced, otherwise `radiance` itself); `report` holds the counts.

    Raises:
        NonFiniteError: under "strict" when any NaN, ±Inf or negative value is present; under
            "raise" the same, except tiny negatives (see `SanitizePolicy`), which become 0.
        ValueError: when `policy` is unknown.

    Example:
        >>> import numpy as np
        >>> x = np.array([1.0, np.nan, np.inf, -2.0, 3.0], np.float32)
        >>> y, report = sanitize(x, "clamp")
        >>> y.tolist(), report.describe()
        ([1.0, 0.0, 3.0, 0.0, 3.0], '1 NaN, 1 +Inf, 0 -Inf, 1 negative')
    """
    if not _is_policy(policy):
        raise ValueError(
            f"`policy` must be one of {', '.join(repr(p) for p in _POLICIES)}; got {policy!r}."
        )
    arr = np.asarray(radiance)
    if not np.issubdtype(arr.dtype, np.floating):
        negative = (
            arr < 0 if np.issubdtype(arr.dtype, np.signedinteger) else np.zeros(arr.shape, bool)
        )
        nan = posinf = neginf = np.zeros(arr.shape, bool)
    else:
        nan = np.isnan(arr)
        posinf = np.isposinf(arr)
        neginf = np.isneginf(arr)
        negative = arr < 0  # NaN compares False; -Inf is counted as -Inf only
        negative &= ~neginf
    found = SanitizeReport(
        num_nan=int(nan.sum()),
        num_posinf=int(posinf.sum()),
        num_neginf=int(neginf.sum()),
        num_negative=int(negative.sum()),
        policy=policy,
    )
    if found.clean:
        return arr, found
    if policy == "raise" and _only_tiny_negatives(arr, found):
        out = arr.copy()
        out[negative] = 0
        report = dataclasses.replace(found, tiny_negatives_clamped=True)
        logger.info(
            "%s: %d tiny negative value(s) (lossy compression noise, down to %.3g) set to 0; "
            "pass sanitize='strict' to refuse them instead",
            name,
            found.num_negative,
            float(arr[negative].min()),
        )
        return out, report
    if policy in ("raise", "strict"):
        report = found
        raise NonFiniteError(
            f'`{name}` holds {report.describe()} value(s). Pass `sanitize="zero"` (set them to 0) '
            'or `sanitize="clamp"` (+Inf -> largest finite value, the rest -> 0), '
            "or repair the source."
        )
    if policy == "zero":
        replacement = 0.0
    elif policy == "clamp":
        finite = arr[np.isfinite(arr)]
        replacement = float(finite.max()) if finite.size else 0.0
        replacement = max(replacement, 0.0)
    else:  # pragma: no cover - the check above rejected everything else
        assert_never(policy)
    out = arr.copy()
    out[nan | neginf | negative] = 0
    out[posinf] = replacement
    report = dataclasses.replace(found, posinf_replacement=replacement)
    logger.info("sanitized %s with policy %r: %s", name, policy, report.describe())
    return out, report


def _only_tiny_negatives(arr: np.ndarray, found: SanitizeReport) -> bool:
    """True when the only problem is a few negatives far below the map's scale (compression noise)."""
    if found.num_nan or found.num_posinf or found.num_neginf or not found.num_negative:
        return False
    if not np.issubdtype(arr.dtype, np.floating):
        return False
    if found.num_negative > TINY_NEGATIVE_FRACTION * arr.size:
        return False
    scale = float(np.abs(arr, dtype=np.float64).mean())
    return scale > 0 and float(-arr.min()) <= TINY_NEGATIVE_RELATIVE * scale
