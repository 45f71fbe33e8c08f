"""A small phrase grammar for lighting: "golden hour, hazy, from the left", "softbox from the left".

`read_phrase(text)` reads a phrase word by word (case and punctuation ignored, hyphens split words)
and matches the longest known phrase at each word. It never fails on a word it does not know: the
`PhraseReading` lists what it understood, the filler words it skipped and the words it did not know
(the CLI's `--strict` refuses those).

Vocabulary (`VOCABULARY` holds it as data; docs/tutorials/skies.md shows it):

| kind | phrases | meaning |
|---|---|---|
| time of day | dawn, sunrise, morning, noon / midday, afternoon, golden hour, evening, sunset, dusk, twilight / blue hour, night / midnight | the sun's elevation and a default azimuth (east in the morning, south at noon, west later; +y is north) |
| weather | clear / sunny, hazy / haze / misty, overcast / cloudy / grey / gray | Preetham turbidity 2.5 or 6; the CIE overcast sky |
| colour | warm, cool / cold | a luminance-neutral tint of the whole map |
| direction | from the left / right / front, from behind / the back, backlit, from above / overhead, from the north / east / south / west (also without "from", "the", or with "side") | the azimuth (or elevation) of the last light named, else of the sun or the first light |
| studio | studio, softbox, key light / key / studio key light, spotlight / spot, rim light / rim / back light, fill light / fill | a studio map (`gaffer_envmap.studio`) with these lights; "studio" alone: a softbox key and a fill |
| filler | a, an, the, and, with, at, in, on, of, light, lights, lit, lighting, sky, day, time, setup, scene | nothing |

Directions are those of a camera looking along world +y (Blender's front view): left = azimuth 270
(-x), right = 90 (+x), behind the subject = 0 (+y), front (the camera's side) = 180 (-y); the compass
words read +y as north and +x as east, as the ephemeris does (`gaffer_envmap.sun_position`). A fill
light without a direction goes opposite the first light (mirrored left/right). When a phrase names a
studio light, time of day and weather are noted and ignored.
"""

import re
from dataclasses import dataclass
from typing import Literal

from gaffer_envmap.sky import (
    DEFAULT_EXPOSURE_EV,
    DEFAULT_GROUND_ALBEDO,
    DEFAULT_TURBIDITY,
    SkyConfig,
    SkyModel,
    SunPosition,
)
from gaffer_envmap.studio import LightKind, StudioConfig, StudioLight, default_light

__all__ = [
    "DEFAULT_SUN",
    "VOCABULARY",
    "PhraseReading",
    "read_phrase",
]

_Kind = Literal["time", "weather", "tint", "direction", "light", "studio", "filler"]

# time of day -> (sun elevation deg, default azimuth deg)
_TIMES: dict[str, tuple[float, float]] = {
    "dawn": (-4.0, 90.0),
    "sunrise": (1.0, 90.0),
    "morning": (25.0, 120.0),
    "noon": (60.0, 180.0),
    "afternoon": (35.0, 240.0),
    "golden hour": (6.0, 270.0),
    "evening": (12.0, 270.0),
    "sunset": (1.0, 270.0),
    "dusk": (-4.0, 270.0),
    "twilight": (-6.0, 270.0),
    "night": (-25.0, 0.0),
}
_TIME_SYNONYMS = {"midday": "noon", "blue hour": "twilight", "midnight": "night"}

# weather -> (model, turbidity)
_WEATHER: dict[str, tuple[SkyModel, float | None]] = {
    "clear": ("preetham", 2.5),
    "hazy": ("preetham", 6.0),
    "overcast": ("cie-overcast", None),
}
_WEATHER_SYNONYMS = {
    "sunny": "clear",
    "haze": "hazy",
    "misty": "hazy",
    "cloudy": "overcast",
    "grey": "overcast",
    "gray": "overcast",
}

_WARM = (1.12, 1.0, 0.82)
_COOL = (0.86, 1.0, 1.2)
_TINTS = {"warm": _WARM, "cool": _COOL}
_TINT_SYNONYMS = {"cold": "cool"}

# direction -> (azimuth deg or None, elevation deg or None)
_DIRECTIONS: dict[str, tuple[float | None, float | None]] = {
    "left": (270.0, None),
    "right": (90.0, None),
    "behind": (0.0, None),
    "front": (180.0, None),
    "above": (None, 80.0),
    "north": (0.0, None),
    "east": (90.0, None),
    "south": (180.0, None),
    "west": (270.0, None),
}
_DIRECTION_WORDS = {
    "left": "left",
    "right": "right",
    "behind": "behind",
    "back": "behind",
    "front": "front",
    "above": "above",
    "top": "above",
    "north": "north",
    "east": "east",
    "south": "south",
    "west": "west",
}

_LIGHTS: dict[str, LightKind] = {
    "softbox": "softbox",
    "studio key light": "key",
    "key light": "key",
    "key": "key",
    "keylight": "key",
    "spotlight": "spot",
    "spot light": "spot",
    "spot": "spot",
    "rim light": "rim",
    "rim": "rim",
    "back light": "rim",
    "backlight": "rim",
    "fill light": "fill",
    "fill": "fill",
}

_FILLERS = frozenset(
    "a an the and with at in on of light lights lit lighting sky day time setup scene".split()
)

DEFAULT_SUN = SunPosition(elevation_deg=45.0, azimuth_deg=135.0)
"""The sun of a phrase with no time of day (mid-morning, from the front-right)."""


def _table() -> dict[tuple[str, ...], tuple[_Kind, str]]:
    """Every known phrase (as a word tuple) -> (kind, canonical meaning key)."""
    table: dict[tuple[str, ...], tuple[_Kind, str]] = {}
    for name in _TIMES:
        table[tuple(name.split())] = ("time", name)
    for name, canon in _TIME_SYNONYMS.items():
        table[tuple(name.split())] = ("time", canon)
    for name in _WEATHER:
        table[(name,)] = ("weather", name)
    for name, canon in _WEATHER_SYNONYMS.items():
        table[(name,)] = ("weather", canon)
    for name in _TINTS:
        table[(name,)] = ("tint", name)
    for name, canon in _TINT_SYNONYMS.items():
        table[(name,)] = ("tint", canon)
    for word, canon in _DIRECTION_WORDS.items():
        for lead in ((), ("from",), ("from", "the"), ("the",)):
            table[(*lead, word)] = ("direction", canon)
            table[(*lead, word, "side")] = ("direction", canon)
    for phrase in ("backlit", "back lit", "overhead", "from overhead"):
        table[tuple(phrase.split())] = ("direction", "above" if "overhead" in phrase else "behind")
    for name, kind in _LIGHTS.items():
        table[tuple(name.split())] = ("light", kind)
    table[("studio",)] = ("studio", "studio")
    for word in _FILLERS:
        table.setdefault((word,), ("filler", word))
    return table


_TABLE = _table()
_LONGEST = max(len(k) for k in _TABLE)

VOCABULARY: dict[str, tuple[str, ...]] = {
    "time of day": (*_TIMES, *_TIME_SYNONYMS),
    "weather": (*_WEATHER, *_WEATHER_SYNONYMS),
    "colour": (*_TINTS, *_TINT_SYNONYMS),
    "direction": (
        "from the left",
        "from the right",
        "from the front",
        "from behind",
        "from the back",
        "backlit",
        "from above",
        "overhead",
        "from the north / east / south / west",
    ),
    "studio": ("studio", *_LIGHTS),
    "filler": tuple(sorted(_FILLERS)),
}
"""Every phrase `read_phrase` knows, by kind (the grammar's documentation as data)."""


def _unit_luminance(rgb: tuple[float, float, float]) -> tuple[float, float, float]:
    lum = 0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
    return (rgb[0] / lum, rgb[1] / lum, rgb[2] / lum)


@dataclass(frozen=True, kw_only=True)
class PhraseReading:
    """What `read_phrase` understood. Fields left None were not said.

    Attributes:
        text: the phrase as given.
        understood: (words, meaning) for every phrase it matched, in order.
        ignored: filler words it skipped.
        unknown: words it did not know, in order, without repeats.
        notes: remarks (a later word overriding an earlier one, words a studio ignores).
        sun_elevation_deg: from a time of day or "from above".
        sun_azimuth_deg: from a time of day or a direction.
        model: from the weather.
        turbidity: from the weather.
        tint_rgb: from warm / cool (luminance 1).
        lights: studio lights; None for an outdoor sky.
    """

    text: str
    understood: tuple[tuple[str, str], ...]
    ignored: tuple[str, ...]
    unknown: tuple[str, ...]
    notes: tuple[str, ...]
    sun_elevation_deg: float | None = None
    sun_azimuth_deg: float | None = None
    model: SkyModel | None = None
    turbidity: float | None = None
    tint_rgb: tuple[float, float, float] | None = None
    lights: tuple[StudioLight, ...] | None = None

    @property
    def is_studio(self) -> bool:
        """True when the phrase describes a studio rather than a sky."""
        return self.lights is not None

    def scene(
        self, *, exposure_ev: float | int = DEFAULT_EXPOSURE_EV, sun: SunPosition | None = None
    ) -> SkyConfig | StudioConfig:
        """The sky or studio the phrase describes, with defaults for what it did not say.

        Args:
            exposure_ev: the map's exposure.
            sun: a sun position that overrides the phrase's (an ephemeris, explicit angles).

        Example:
            >>> read_phrase("sunset from the left").scene().sun.azimuth_deg
            270.0
        """
        tint = self.tint_rgb or (1.0, 1.0, 1.0)
        if self.lights is not None:
            return StudioConfig(lights=self.lights, exposure_ev=exposure_ev, tint_rgb=tint)
        if sun is None:
            sun = SunPosition(
                elevation_deg=(
                    DEFAULT_SUN.elevation_deg
                    if self.sun_elevation_deg is None
                    else self.sun_elevation_deg
                ),
                azimuth_deg=(
                    DEFAULT_SUN.azimuth_deg
                    if self.sun_azimuth_deg is None
                    else self.sun_azimuth_deg
                ),
            )
        return SkyConfig(
            sun=sun,
            model=self.model or "preetham",
            turbidity=DEFAULT_TURBIDITY if self.turbidity is None else self.turbidity,
            ground_albedo=(DEFAULT_GROUND_ALBEDO, DEFAULT_GROUND_ALBEDO, DEFAULT_GROUND_ALBEDO),
            exposure_ev=exposure_ev,
            tint_rgb=tint,
        )

    def describe(self) -> list[str]:
        """Lines for a person: what was understood, skipped and not known."""
        lines = []
        if self.understood:
            lines.append(
                "understood: "
                + "; ".join(f'"{words}" -> {meaning}' for words, meaning in self.understood)
            )
        else:
            lines.append("understood: nothing")
        lines.extend(f"note: {note}" for note in self.notes)
        if self.unknown:
            lines.append("not understood (ignored): " + ", ".join(self.unknown))
        return lines


class _Reader:
    """The state of one `read_phrase` call (the last light, a direction waiting for a target)."""

    def __init__(self, text: str) -> None:
        self.text = text
        self.understood: list[tuple[str, str]] = []
        self.ignored: list[str] = []
        self.unknown: list[str] = []
        self.notes: list[str] = []
        self.time: str | None = None
        self.weather: str | None = None
        self.tint: str | None = None
        self.studio_word = False
        # lights as [kind, azimuth or None, elevation or None]
        self.lights: list[list] = []
        self.sun_direction: list[float | None] = [None, None]
        self.pending: list[float | None] | None = None

    def _set(self, slot: str, value: str, what: str) -> None:
        old = getattr(self, slot)
        if old is not None and old != value:
            self.notes.append(f'"{value}" replaces "{old}" ({what}: the last one counts)')
        setattr(self, slot, value)

    def take(self, words: str, kind: _Kind, key: str) -> None:
        if kind == "filler":
            self.ignored.append(words)
            return
        if kind == "time":
            el, az = _TIMES[key]
            self._set("time", key, "time of day")
            self.understood.append((words, f"{key}: sun elevation {el:g} deg, azimuth {az:g} deg"))
        elif kind == "weather":
            _model, turbidity = _WEATHER[key]
            self._set("weather", key, "weather")
            meaning = f"turbidity {turbidity:g}" if turbidity is not None else "CIE overcast sky"
            self.understood.append((words, f"{key}: {meaning}"))
        elif kind == "tint":
            self._set("tint", key, "colour")
            self.understood.append((words, f"{key} tint"))
        elif kind == "direction":
            self._direction(words, key)
        elif kind == "light":
            self.lights.append([key, None, None])
            if self.pending is not None:  # "from the left, a softbox"
                self._apply(self.lights[-1], self.pending, skip=1)
                self.pending = None
            self.understood.append((words, f"studio {key} light"))
        elif kind == "studio":
            self.studio_word = True
            self.understood.append((words, "studio scene"))

    @staticmethod
    def _apply(target: list, direction: list[float | None], skip: int = 0) -> None:
        az, el = direction
        if az is not None:
            target[skip] = az
        if el is not None:
            target[skip + 1] = el

    def _direction(self, words: str, key: str) -> None:
        az, el = _DIRECTIONS[key]
        if self.lights:
            self._apply(self.lights[-1], [az, el], skip=1)
            target = f"the {self.lights[-1][0]} light"
        else:
            self.pending = [az, el] if self.pending is None else self.pending
            self._apply(self.pending, [az, el])
            target = "the sun (or the first light)"
        what = f"azimuth {az:g} deg" if az is not None else f"elevation {el:g} deg"
        self.understood.append((words, f"{key}: {target} at {what}"))

    def reading(self) -> PhraseReading:
        tint = _unit_luminance(_TINTS[self.tint]) if self.tint else None
        if self.lights or self.studio_word:
            return self._studio_reading(tint)
        el = az = None
        if self.time is not None:
            el, az = _TIMES[self.time]
        if self.pending is not None:
            az = self.pending[0] if self.pending[0] is not None else az
            el = self.pending[1] if self.pending[1] is not None else el
        model, turbidity = _WEATHER[self.weather] if self.weather else (None, None)
        return PhraseReading(
            text=self.text,
            understood=tuple(self.understood),
            ignored=tuple(self.ignored),
            unknown=tuple(dict.fromkeys(self.unknown)),
            notes=tuple(self.notes),
            sun_elevation_deg=el,
            sun_azimuth_deg=az,
            model=model,
            turbidity=turbidity,
            tint_rgb=tint,
        )

    def _studio_reading(self, tint: tuple[float, float, float] | None) -> PhraseReading:
        notes = list(self.notes)
        for slot in ("time", "weather"):
            if getattr(self, slot) is not None:
                notes.append(f'"{getattr(self, slot)}" is ignored: the phrase describes a studio')
        specs = self.lights or [["softbox", None, None], ["fill", None, None]]
        if self.pending is not None:  # a direction before any light: the first light's
            self._apply(specs[0], self.pending, skip=1)
        lights: list[StudioLight] = []
        for kind, az, el in specs:
            if kind == "fill" and az is None and lights:
                az = (360.0 - lights[0].azimuth_deg) % 360.0  # mirror the key left <-> right
            lights.append(default_light(kind, azimuth_deg=az, elevation_deg=el))
        return PhraseReading(
            text=self.text,
            understood=tuple(self.understood),
            ignored=tuple(self.ignored),
            unknown=tuple(dict.fromkeys(self.unknown)),
            notes=tuple(notes),
            tint_rgb=tint,
            lights=tuple(lights),
        )


def read_phrase(text: str) -> PhraseReading:
    """Read a lighting phrase (grammar in the module docstring).

    Args:
        text: e.g. "golden hour, hazy, warm, from the left" or "softbox from the left".

    Returns:
        A `PhraseReading`; its `unknown` lists the words it did not know (never an error here).

    Example:
        >>> r = read_phrase("Hazy golden-hour sky from the left, fluffy")
        >>> (r.sun_elevation_deg, r.sun_azimuth_deg, r.turbidity, r.unknown)
        (6.0, 270.0, 6.0, ('fluffy',))
    """
    words = re.findall(r"[^\W_]+", str(text).lower())
    reader = _Reader(str(text))
    i = 0
    while i < len(words):
        for n in range(min(_LONGEST, len(words) - i), 0, -1):
            key = tuple(words[i : i + n])
            if key in _TABLE:
                kind, canon = _TABLE[key]
                reader.take(" ".join(key), kind, canon)
                i += n
                break
        else:
            if words[i] == "from":  # a dangling "from" (its direction unknown) is a filler
                reader.ignored.append("from")
            else:
                reader.unknown.append(words[i])
            i += 1
    return reader.reading()
