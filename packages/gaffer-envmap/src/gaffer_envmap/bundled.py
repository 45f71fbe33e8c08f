"""The CC0 HDRIs shipped with gaffer-envmap (Poly Haven 1K versions, as bundled with Blender).

They are the embedded default for demos, tests and the built-in dataset recipe: no downloads needed.
Licence and sources: data/hdri/LICENSE.txt.
"""

from importlib import resources
from pathlib import Path

from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import EnvmapReadError


def bundled_hdris() -> dict[str, Path]:
    """Name -> path of each shipped HDRI (1024x512 float EXR, Blender convention, linear Rec.709)."""
    root = Path(str(resources.files("gaffer_envmap") / "data" / "hdri"))
    return {p.stem: p for p in sorted(root.glob("*.exr"))}


def bundled_hdri(name: str) -> Path:
    """Path of one shipped HDRI by name (city, courtyard, forest, interior, night, studio, sunrise, sunset).

    Raises:
        EnvmapReadError: for an unknown name; the message lists the shipped ones.
    """
    maps = bundled_hdris()
    if name not in maps:
        raise EnvmapReadError(
            f"`name` {name!r} is not a bundled HDRI; choose one of {sorted(maps)}."
        )
    return maps[name]


def read_bundled_hdri(name: str) -> "EnvironmentMap":
    """Load a shipped HDRI as an `EnvironmentMap` (Blender convention).

    The files are DWAB-compressed (lossy), which leaves a handful of tiny negative values (e.g. 4 in
    "sunset"); they are set to zero here, which is what `sanitize="zero"` does.
    """
    from gaffer_envmap.io import read_envmap

    return read_envmap(bundled_hdri(name), sanitize="zero")
