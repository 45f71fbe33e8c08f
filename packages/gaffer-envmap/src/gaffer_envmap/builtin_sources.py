"""gaffer-envmap's own lighting source, registered like any plugin (entry point `sky` in the group
`gaffer.envmap_sources`, in gaffer-envmap's pyproject.toml): the phrase grammar
(`gaffer_envmap.phrase`) drawn as a Preetham / CIE overcast sky (`gaffer_envmap.sky`) or a studio
(`gaffer_envmap.studio`). `gaffer-envmap sky --text PHRASE --source sky` gives the same map as
`gaffer-envmap sky --text PHRASE`.

Options (`--source-option KEY=VALUE`): `exposure` (stops, default -3, as `--exposure`), `strict` (1:
refuse a word the grammar does not know, as `--strict`).
"""

import math
from collections.abc import Mapping

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ParameterError
from gaffer_envmap.sources import EnvmapSource

__all__ = ["SKY"]


def _exposure(options: Mapping[str, str]) -> float:
    from gaffer_envmap.sky import DEFAULT_EXPOSURE_EV

    text = options.get("exposure")
    if text is None:
        return DEFAULT_EXPOSURE_EV
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and -40 <= value <= 40):
        raise ParameterError(f"option `exposure` is {text!r}; pass stops in [-40, 40], e.g. -3.")
    return value


def _strict(options: Mapping[str, str]) -> bool:
    text = options.get("strict", "0").lower()
    if text not in ("0", "1", "true", "false", "yes", "no"):
        raise ParameterError(f"option `strict` is {text!r}; pass 1 or 0.")
    return text in ("1", "true", "yes")


def _sky_from_text(text: str, *, width: int, options: Mapping[str, str]) -> EnvironmentMap:
    """The phrase's sky or studio, `[width // 2, width, 3]` (the grammar: docs/tutorials/skies.md)."""
    from gaffer_envmap.phrase import read_phrase
    from gaffer_envmap.sky import SkyConfig, sky_envmap
    from gaffer_envmap.studio import studio_envmap

    exposure = _exposure(options)
    reading = read_phrase(text)
    if _strict(options) and reading.unknown:
        words = ", ".join(repr(w) for w in reading.unknown)
        raise ParameterError(f"word(s) {words} are not in the grammar (strict); drop them.")
    scene = reading.scene(exposure_ev=exposure)
    if isinstance(scene, SkyConfig):
        return sky_envmap(scene, width)
    return studio_envmap(scene, width)


SKY = EnvmapSource(
    name="sky",
    description="the built-in phrase grammar: a Preetham / CIE overcast sky or a studio "
    "(docs/tutorials/skies.md)",
    from_text=_sky_from_text,
    options=("exposure", "strict"),
)
"""The built-in source "sky" (text only)."""
