"""The sun's position for a place and a time, from an ephemeris (`astral`, the optional extra `sky`).

`astral` (Apache-2.0, pure Python) gives the sun's elevation (with atmospheric refraction) and its
compass azimuth (clockwise from north). With world +y read as north and +x as east, the compass
azimuth is exactly the azimuth of `gaffer_envmap.sky` (Blender's `sun_rotation` sense), so a map made
for a place and time has north at u = 0.25 and east at the centre column.
"""

import math
from datetime import datetime
from types import ModuleType

from gaffer_envmap.errors import MissingDependencyError, ParameterError
from gaffer_envmap.sky import SunPosition

__all__ = ["INSTALL_HINT", "parse_place", "parse_time", "require_astral", "sun_position_at"]

INSTALL_HINT = 'pip install "gaffer-envmap[sky]"'
"""The command that installs the ephemeris."""


def require_astral() -> ModuleType:
    """Import `astral.sun`, or raise `MissingDependencyError` naming the extra that installs it."""
    try:
        import astral.sun
    except ImportError as exc:
        raise MissingDependencyError(
            f"the sun's position for a place and time needs `astral`, which is not installed; "
            f"run: {INSTALL_HINT}"
        ) from exc
    return astral.sun


def parse_place(text: str, argument: str = "place") -> tuple[float, float]:
    """A place "LAT,LON" in decimal degrees (north and east positive) -> (latitude, longitude).

    Args:
        text: the place, e.g. "48.8584,2.2945".
        argument: the name messages give the value (the CLI passes "--at").

    Raises:
        ParameterError: not two finite numbers, or out of [-90, 90] x [-180, 180].

    Example:
        >>> parse_place("48.8584, 2.2945")
        (48.8584, 2.2945)
    """
    parts = [p.strip() for p in str(text).split(",")]
    try:
        lat, lon = (float(p) for p in parts)
    except ValueError:
        raise ParameterError(
            f"`{argument}` {text!r} is not LAT,LON; pass two decimal degrees, north and east positive, "
            "e.g. 48.8584,2.2945."
        ) from None
    if not (math.isfinite(lat) and math.isfinite(lon)) or abs(lat) > 90 or abs(lon) > 180:
        raise ParameterError(
            f"`{argument}` {text!r} is out of range; latitude must be in [-90, 90] and longitude in "
            "[-180, 180]."
        )
    return lat, lon


def parse_time(text: str, argument: str = "time") -> datetime:
    """An ISO 8601 date and time WITH a UTC offset ("2026-06-21T12:00+02:00", "...Z").

    A time without an offset is refused: the sun's position depends on the actual instant, and a
    guessed time zone would move it by up to 15 degrees an hour.

    Args:
        text: the date and time.
        argument: the name messages give the value (the CLI passes "--time").

    Raises:
        ParameterError: unparseable, or no offset.

    Example:
        >>> parse_time("2026-06-21T12:00+02:00").utcoffset().total_seconds()
        7200.0
    """
    try:
        when = datetime.fromisoformat(str(text).strip())
    except ValueError:
        raise ParameterError(
            f"`{argument}` {text!r} is not an ISO 8601 date and time; pass e.g. 2026-06-21T12:00+02:00."
        ) from None
    if when.tzinfo is None or when.utcoffset() is None:
        raise ParameterError(
            f"`{argument}` {text!r} has no UTC offset; add one, e.g. {when.isoformat(timespec='minutes')}"
            "+02:00 (or Z for UTC)."
        )
    return when


def sun_position_at(
    latitude_deg: float | int, longitude_deg: float | int, when: datetime
) -> SunPosition:
    """Where the sun is seen from a place at an instant (elevation with refraction, compass azimuth).

    Args:
        latitude_deg: north positive, [-90, 90].
        longitude_deg: east positive, [-180, 180].
        when: a timezone-aware datetime.

    Returns:
        A `SunPosition` whose azimuth is the compass azimuth (0 north = world +y, 90 east = +x).

    Raises:
        ParameterError: a naive datetime or coordinates out of range.
        MissingDependencyError: `astral` is not installed (`pip install "gaffer-envmap[sky]"`).

    Example:
        >>> from datetime import timezone
        >>> noon = datetime(2024, 3, 20, 12, 7, tzinfo=timezone.utc)  # equinox, Greenwich
        >>> round(sun_position_at(0.0, 0.0, noon).elevation_deg)  # the sun overhead the equator
        90
    """
    if when.tzinfo is None or when.utcoffset() is None:
        raise ParameterError("`when` has no time zone; pass a timezone-aware datetime.")
    if abs(latitude_deg) > 90 or abs(longitude_deg) > 180:
        raise ParameterError(
            f"`latitude`, `longitude` ({latitude_deg}, {longitude_deg}) out of range; pass "
            "latitude in [-90, 90] and longitude in [-180, 180]."
        )
    sun = require_astral()
    from astral import Observer

    observer = Observer(latitude=latitude_deg, longitude=longitude_deg)
    return SunPosition(
        elevation_deg=float(sun.elevation(observer, when, with_refraction=True)),
        azimuth_deg=float(sun.azimuth(observer, when)),
    )
