"""The one definition of the lighting-encoding modes ("compat"), shared by every package and CLI.

- "default": gaffer's corrected pipeline (rotation in linear light with area filtering, float encodings).
- "neural-gaffer": the authors' pipeline bit for bit (`gaffer_envmap.compat`), for their released
  checkpoint (paper section 3.2; the official implementation's turntable and encodings).

gaffer-diffusion and gaffer-nerf take `Compat`, `COMPAT_MODES` (argparse `choices`) and `compat_problem`
(the wording of the refusal) from here instead of spelling the modes out again.
"""

from typing import TYPE_CHECKING, Literal, TypeAlias, TypeGuard, get_args

Compat = Literal["default", "neural-gaffer"]

if TYPE_CHECKING:
    CompatArg: TypeAlias = Compat
else:
    CompatArg = str
"""A `compat` parameter: `Compat` to the type checker, any str at run time, because the function
refuses an unknown mode itself (with `compat_problem`'s wording), also under the test-time type hook."""

COMPAT_MODES: tuple[Compat, ...] = get_args(Compat)
"""Every mode, default first: the `choices` of each `--compat` flag."""


def is_compat(value: object) -> TypeGuard[Compat]:
    """True when `value` names a mode of `COMPAT_MODES`."""
    return isinstance(value, str) and value in COMPAT_MODES


def compat_problem(arg: str, value: object) -> str | None:
    """The one-line refusal for a bad mode, naming the argument, or None when `value` is a mode.

    Each package raises it as its own error type.

    Example:
        >>> compat_problem("compat", "authors")
        "`compat` is 'authors'; expected one of 'default', 'neural-gaffer'."
        >>> compat_problem("compat", "default") is None
        True
    """
    if is_compat(value):
        return None
    choices = ", ".join(repr(m) for m in COMPAT_MODES)
    return f"`{arg}` is {value!r}; expected one of {choices}."
