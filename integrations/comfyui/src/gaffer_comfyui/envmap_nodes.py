"""Environment-map nodes: load a map (a file or a bundled CC0 HDRI), turn it, or make one from words.

Every output map is a `GAFFER_ENVMAP` (linear HDR float32, `types.GafferEnvmap`); the IMAGE beside it
is only a tone-mapped preview (`gaffer_envmap.preview.tonemap_preview`: median luminance to 0.18,
Reinhard, sRGB) for looking at, never for lighting.
"""

import math
from pathlib import Path
from typing import Any

import numpy as np

from ._boundary import comfy_input_dir, library_errors
from ._convert import preview_image
from .errors import NodeInputError
from .types import GAFFER_ENVMAP, GafferEnvmap

CATEGORY = "Neural Gaffer"

SANITIZE_POLICIES = ("raise", "strict", "zero", "clamp")
"""gaffer-envmap's NaN/Inf/negative policies (`gaffer_envmap.sanitize.SANITIZE_POLICIES`, the
choices of every gaffer CLI's `--sanitize`); kept literal so INPUT_TYPES needs no import."""

ENVMAP_SUFFIXES = (".exr", ".hdr")

PREVIEW_HEIGHT = 256
"""Rows of an envmap preview IMAGE (512 columns); larger maps are shrunk power-exactly for it."""


def envmap_preview(env: GafferEnvmap) -> Any:
    """`[1, h, 2h, 3]` IMAGE: the map tone-mapped for display, at most `PREVIEW_HEIGHT` rows."""
    from gaffer_envmap.preview import tonemap_preview
    from gaffer_envmap.resample import resize_conservative

    e = env.envmap
    if e.height > PREVIEW_HEIGHT:
        e = resize_conservative(e, PREVIEW_HEIGHT)
    return preview_image(tonemap_preview(e.radiance_linear))


def bundled_names() -> list[str]:
    """The CC0 HDRIs shipped with gaffer-envmap (city, courtyard, ...)."""
    from gaffer_envmap.bundled import bundled_hdris

    return sorted(bundled_hdris())


def resolve_envmap(node: str, text: str) -> Path:
    """A bundled HDRI's name, or an .exr/.hdr path (absolute, from the working folder, or from
    ComfyUI's input folder).

    Raises:
        NodeInputError: an empty value, a missing file, or another file type.
    """
    from gaffer_envmap.bundled import bundled_hdris

    name = str(text).strip()
    bundled = bundled_hdris()
    if name in bundled:
        return bundled[name]
    if not name:
        raise NodeInputError(
            f"{node}: `envmap` is empty; type a bundled HDRI's name ({', '.join(sorted(bundled))}) "
            "or the path of an .exr/.hdr file."
        )
    path = Path(name).expanduser()
    inputs = comfy_input_dir()
    if not path.is_absolute() and not path.exists() and inputs is not None:
        path = inputs / path
    if not path.is_file():
        raise NodeInputError(
            f"{node}: `envmap` {name!r} is neither a bundled HDRI ({', '.join(sorted(bundled))}) nor "
            "an existing file; give an .exr/.hdr path (absolute, or in ComfyUI's input folder)."
        )
    if path.suffix.lower() not in ENVMAP_SUFFIXES:
        raise NodeInputError(
            f"{node}: `envmap` {path.name!r} is a {path.suffix or 'suffix-less'} file; give an HDR "
            "map (.exr or .hdr): an 8-bit picture has lost the light's energy."
        )
    return path


class NeuralGafferLoadEnvmap:
    """Read an equirectangular HDR map (.exr/.hdr, Blender convention) or a bundled CC0 HDRI."""

    CATEGORY = CATEGORY
    FUNCTION = "load"
    RETURN_TYPES = (GAFFER_ENVMAP, "IMAGE")
    RETURN_NAMES = ("envmap", "preview")
    DESCRIPTION = (
        "An HDR environment map as linear float32 (never clipped to 8 bits), and a tone-mapped "
        "preview. `envmap`: a bundled HDRI's name or an .exr/.hdr path."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {
            "required": {
                "envmap": (
                    "STRING",
                    {
                        "default": "courtyard",
                        "tooltip": "a bundled CC0 HDRI (city, courtyard, forest, interior, night, "
                        "studio, sunrise, sunset) or an .exr/.hdr path, absolute or in ComfyUI's "
                        "input folder; lat-long 2:1, Blender convention (z up)",
                    },
                ),
                "sanitize": (
                    list(SANITIZE_POLICIES),
                    {
                        "default": "raise",
                        "tooltip": "NaN/Inf/negative pixels: 'raise' sets the tiny negatives of "
                        "lossy EXR compression to 0 and refuses anything else; 'strict' refuses any; "
                        "'zero' sets them to 0; 'clamp' also keeps +Inf as the brightest value",
                    },
                ),
            }
        }

    @classmethod
    def IS_CHANGED(cls, envmap: str, sanitize: str) -> str:
        """ComfyUI reruns the node when this changes: the file's modification time and size, so an
        edited map on disk is read again (a missing file: its name, and `load` explains)."""
        try:
            stat = resolve_envmap("NeuralGafferLoadEnvmap", envmap).stat()
        except (NodeInputError, OSError):
            return f"{envmap}|{sanitize}"
        return f"{envmap}|{sanitize}|{stat.st_mtime_ns}|{stat.st_size}"

    def load(self, envmap: str, sanitize: str) -> tuple[GafferEnvmap, Any]:
        node = "NeuralGafferLoadEnvmap"
        if sanitize not in SANITIZE_POLICIES:
            raise NodeInputError(
                f"{node}: `sanitize` is {sanitize!r}; choose one of {list(SANITIZE_POLICIES)}."
            )
        path = resolve_envmap(node, envmap)
        from gaffer_envmap.errors import NonFiniteError
        from gaffer_envmap.io import read_envmap

        try:
            with library_errors(node, f"`envmap` {path.name}"):
                env = read_envmap(path, sanitize=sanitize)  # type: ignore[arg-type]
        except NodeInputError as exc:
            if isinstance(exc.__cause__, NonFiniteError):
                raise NodeInputError(
                    f"{node}: `envmap` {path.name} holds NaN, Inf or negative values that "
                    f"`sanitize` {sanitize!r} refuses; set `sanitize` to 'zero' or 'clamp', or "
                    "repair the file."
                ) from exc.__cause__
            raise
        name = str(envmap).strip()
        label = name if name in bundled_names() else path.name
        out = GafferEnvmap(envmap=env, label=label)
        return out, envmap_preview(out)


def world_rotation(azimuth_deg: float, elevation_deg: float, spin_deg: float) -> np.ndarray:
    """`[3, 3]` world rotation R = Rz(azimuth) Ry(-elevation) Rx(spin) (Blender world, z up).

    The light that came from world +x on the horizon comes from (azimuth, elevation) afterwards, in
    `gaffer_envmap.poses.orbit_w2c_blender`'s angles (azimuth counter-clockwise from +x seen from
    above, elevation above the horizon), and `spin` turns the map about that direction. With
    elevation and spin 0, `azimuth` is the turn about world up that `lighting_from_envmap`'s
    `spin_deg` (and a turntable) applies.
    """
    a, e, s = (math.radians(v) for v in (azimuth_deg, elevation_deg, spin_deg))
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    ry = np.array([[math.cos(e), 0, -math.sin(e)], [0, 1, 0], [math.sin(e), 0, math.cos(e)]])
    rx = np.array([[1, 0, 0], [0, math.cos(s), -math.sin(s)], [0, math.sin(s), math.cos(s)]])
    return rz @ ry @ rx


def rotate_envmap(env: GafferEnvmap, rotation: np.ndarray, label: str) -> GafferEnvmap:
    """The map turned by the world rotation `rotation` (E'(d) = E(R^T d)), at its own size.

    `gaffer_envmap.rotate_to_camera` with the pose `IDENTITY_LAYOUT_W2C . R`: its camera-frame map
    is the world map seen through R, resampled power-exactly (the "conservative" filter)."""
    import torch

    from gaffer_envmap.poses import IDENTITY_LAYOUT_W2C, W2CBlender
    from gaffer_envmap.rotate import rotate_to_camera

    w2c = np.zeros((3, 4))
    w2c[:, :3] = IDENTITY_LAYOUT_W2C.rotation @ rotation
    with torch.no_grad():
        out = rotate_to_camera(env.envmap, W2CBlender(w2c), height=env.envmap.height)
    rad = np.ascontiguousarray(out[0, 0].numpy(), dtype=np.float32).clip(0.0, None)
    return GafferEnvmap(envmap=env.envmap.with_radiance(rad), label=label)


class NeuralGafferRotateEnvmap:
    """Turn an environment map: where its front light goes (azimuth, elevation) and a spin about it."""

    CATEGORY = CATEGORY
    FUNCTION = "rotate"
    RETURN_TYPES = (GAFFER_ENVMAP, "IMAGE")
    RETURN_NAMES = ("envmap", "preview")
    DESCRIPTION = (
        "Rotate the world map: the light that came from world +x now comes from (azimuth, "
        "elevation), and `spin` turns it about that direction. Azimuth alone turns the light about "
        "world up. Resampled power-exactly; all zeros return the map unchanged."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        angle = {"min": -360.0, "max": 360.0, "step": 1.0}
        return {
            "required": {
                "envmap": (GAFFER_ENVMAP,),
                "azimuth": (
                    "FLOAT",
                    {
                        "default": 0.0,
                        **angle,
                        "tooltip": "degrees, counter-clockwise about world up seen from above",
                    },
                ),
                "elevation": (
                    "FLOAT",
                    {
                        "default": 0.0,
                        "min": -90.0,
                        "max": 90.0,
                        "step": 1.0,
                        "tooltip": "degrees the front light is raised above the horizon",
                    },
                ),
                "spin": (
                    "FLOAT",
                    {"default": 0.0, **angle, "tooltip": "degrees about the new front direction"},
                ),
            }
        }

    def rotate(
        self, envmap: GafferEnvmap, azimuth: float, elevation: float, spin: float
    ) -> tuple[GafferEnvmap, Any]:
        node = "NeuralGafferRotateEnvmap"
        _check_envmap(node, "envmap", envmap)
        for name, value, lo, hi in (
            ("azimuth", azimuth, -360.0, 360.0),
            ("elevation", elevation, -90.0, 90.0),
            ("spin", spin, -360.0, 360.0),
        ):
            _check_angle(node, name, value, lo, hi)
        if azimuth % 360.0 == 0 and elevation == 0 and spin % 360.0 == 0:
            return envmap, envmap_preview(envmap)
        label = f"{envmap.label} rotated ({azimuth:g}, {elevation:g}, {spin:g})"
        out = rotate_envmap(envmap, world_rotation(azimuth, elevation, spin), label)
        return out, envmap_preview(out)


def text_sources() -> list[str]:
    """Installed lighting sources that take words: gaffer-envmap's built-in "sky" first, then
    plugins (entry-point group `gaffer.envmap_sources`); broken plugins are left out."""
    from gaffer_envmap.sources import envmap_sources

    names = [e.name for e in envmap_sources() if e.source and "text" in e.source.capabilities]
    return sorted(names, key=lambda n: (n != "sky", n)) or ["sky"]


class NeuralGafferSky:
    """An HDR sky or studio from words ("golden hour from the left"), as `gaffer-envmap sky --text`."""

    CATEGORY = CATEGORY
    FUNCTION = "make"
    RETURN_TYPES = (GAFFER_ENVMAP, "IMAGE")
    RETURN_NAMES = ("envmap", "preview")
    DESCRIPTION = (
        "A physically based sky (Preetham / CIE overcast) or studio from a phrase, through "
        "gaffer-envmap's lighting sources: 'sky' is the built-in grammar (docs/tutorials/skies.md); "
        "installed plugins that take words are listed too."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {
            "required": {
                "text": (
                    "STRING",
                    {
                        "default": "golden hour from the left",
                        "tooltip": "the lighting in words: time of day, weather, direction, or a "
                        "studio ('softbox from the left')",
                    },
                ),
                "source": (text_sources(), {"default": "sky"}),
                "exposure": (
                    "FLOAT",
                    {
                        "default": -3.0,
                        "min": -40.0,
                        "max": 40.0,
                        "step": 0.5,
                        "tooltip": "stops (2**EV); -3 as `gaffer-envmap sky`'s default (sources "
                        "that take an `exposure` option)",
                    },
                ),
                "width": (
                    "INT",
                    {
                        "default": 512,
                        "min": 16,
                        "max": 4096,
                        "step": 2,
                        "tooltip": "columns (even)",
                    },
                ),
                "strict": (
                    "BOOLEAN",
                    {"default": False, "tooltip": "refuse words the grammar does not know"},
                ),
            }
        }

    def make(
        self, text: str, source: str, exposure: float, width: int, strict: bool
    ) -> tuple[GafferEnvmap, Any]:
        node = "NeuralGafferSky"
        words = " ".join(str(text).split())
        if not words:
            raise NodeInputError(
                f"{node}: `text` is empty; describe the lighting, e.g. 'golden hour from the left'."
            )
        _check_angle(node, "exposure", exposure, -40.0, 40.0)
        if not isinstance(width, int) or width < 16 or width % 2:
            raise NodeInputError(f"{node}: `width` is {width!r}; pass an even integer >= 16.")
        from gaffer_envmap.sources import envmap_from_text, load_envmap_source

        with library_errors(node, f"`source` {source!r}"):
            found = load_envmap_source(str(source), flag="source")
        options = {}
        if "exposure" in found.options:
            options["exposure"] = repr(float(exposure))
        if strict and "strict" in found.options:
            options["strict"] = "1"
        with library_errors(node, f"`text` {words!r}"):
            env = envmap_from_text(found, words, width=int(width), options=options, flag="source")
        out = GafferEnvmap(envmap=env, label=words)
        return out, envmap_preview(out)


def _check_envmap(node: str, name: str, value: object) -> None:
    if not isinstance(value, GafferEnvmap):
        raise NodeInputError(
            f"{node}: `{name}` is a {type(value).__name__}; connect a GAFFER_ENVMAP (from "
            "NeuralGafferLoadEnvmap, NeuralGafferSky or NeuralGafferRotateEnvmap)."
        )


def _check_angle(node: str, name: str, value: object, lo: float, hi: float) -> None:
    if not isinstance(value, int | float) or not math.isfinite(value) or not lo <= value <= hi:
        raise NodeInputError(f"{node}: `{name}` is {value!r}; pass a number in [{lo:g}, {hi:g}].")
