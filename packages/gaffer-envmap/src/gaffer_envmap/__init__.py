"""gaffer-envmap: equirectangular HDR lighting math for relighting (the leaf of gaffer; imports no sibling).

Public API re-exported here, loaded lazily (PEP 562): `import gaffer_envmap.augment` or
`gaffer_envmap.atomic` pulls in numpy only, so torch-free processes (Blender workers) can use them.
"""

import importlib
from typing import TYPE_CHECKING, Any

from gaffer_envmap._version import __version__

_EXPORTS: dict[str, str] = {
    "AugmentSpec": "augment",
    "C2WOpenCV": "poses",
    "COMPAT_MODES": "compat_mode",
    "CONVENTIONS": "conventions",
    "Compat": "compat_mode",
    "compat_problem": "compat_mode",
    "is_compat": "compat_mode",
    "ConventionError": "errors",
    "EnvironmentMap": "environment_map",
    "EnvmapReadError": "errors",
    "EnvmapWriteError": "errors",
    "GafferEnvmapError": "errors",
    "GafferError": "errors",
    "HalfOverflowError": "errors",
    "IDENTITY_LAYOUT_W2C": "poses",
    "LatLongConvention": "conventions",
    "LightingEncoding": "encode",
    "MissingDependencyError": "errors",
    "NonFiniteError": "errors",
    "OutputPathError": "errors",
    "PixelAlignment": "environment_map",
    "PoseError": "errors",
    "SanitizeReport": "sanitize",
    "ShapeError": "errors",
    "W2CBlender": "poses",
    "augment_pool": "augment",
    "augment_specs": "augment",
    "bundled_hdri": "bundled",
    "bundled_hdris": "bundled",
    "chirality": "conventions",
    "convert_convention": "convention_transforms",
    "cube_to_latlong": "cube",
    "describe": "stats",
    "direction_grid": "conventions",
    "direction_to_uv": "conventions",
    "encode_lighting": "encode",
    "first_moment": "stats",
    "flip_horizontal": "augment",
    "get_convention": "conventions",
    "hdr_encode": "encode",
    "directionality": "sh",
    "irradiance": "sh",
    "latlong_to_cube": "cube",
    "ldr_encode": "encode",
    "look_at_w2c_blender": "poses",
    "mean_light_direction": "stats",
    "orbit_w2c_blender": "poses",
    "procedural_envmap": "procedural",
    "physical_envmap": "procedural_physical",
    "project_sh": "sh",
    "read_bundled_hdri": "bundled",
    "read_envmap": "io",
    "read_image_array": "io",
    "reconstruct_sh": "sh",
    "resize_conservative": "resample",
    "resize_conservative_torch": "resample",
    "rotate_to_camera": "rotate",
    "row_solid_angle": "conventions",
    "sanitize": "sanitize",
    "sh_basis": "sh",
    "solid_angle": "conventions",
    "to_center_alignment": "convention_transforms",
    "total_power": "stats",
    "uv_to_direction": "conventions",
    "write_envmap": "io",
    "write_png": "io",
    "ParameterError": "errors",
    "PhraseReading": "phrase",
    "SkyConfig": "sky",
    "StudioConfig": "studio",
    "StudioLight": "studio",
    "SunPosition": "sky",
    "read_phrase": "phrase",
    "sky_envmap": "sky",
    "studio_envmap": "studio",
    "sun_direction": "sky",
    "sun_position_at": "sun_position",
    "yaw_roll": "augment",
    "EnvmapSource": "sources",
    "EnvmapSourceError": "errors",
    "envmap_from_photo": "sources",
    "envmap_from_text": "sources",
    "envmap_sources": "sources",
    "load_envmap_source": "sources",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gaffer_envmap' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"gaffer_envmap.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # static re-exports for type checkers and IDEs
    from gaffer_envmap.augment import (
        AugmentSpec,
        augment_pool,
        augment_specs,
        flip_horizontal,
        yaw_roll,
    )
    from gaffer_envmap.bundled import bundled_hdri, bundled_hdris, read_bundled_hdri
    from gaffer_envmap.compat_mode import COMPAT_MODES, Compat, compat_problem, is_compat
    from gaffer_envmap.convention_transforms import convert_convention, to_center_alignment
    from gaffer_envmap.conventions import (
        CONVENTIONS,
        LatLongConvention,
        chirality,
        direction_grid,
        direction_to_uv,
        get_convention,
        row_solid_angle,
        solid_angle,
        uv_to_direction,
    )
    from gaffer_envmap.cube import cube_to_latlong, latlong_to_cube
    from gaffer_envmap.encode import LightingEncoding, encode_lighting, hdr_encode, ldr_encode
    from gaffer_envmap.environment_map import EnvironmentMap, PixelAlignment
    from gaffer_envmap.errors import (
        ConventionError,
        EnvmapReadError,
        EnvmapSourceError,
        EnvmapWriteError,
        GafferEnvmapError,
        GafferError,
        HalfOverflowError,
        MissingDependencyError,
        NonFiniteError,
        OutputPathError,
        ParameterError,
        PoseError,
        ShapeError,
    )
    from gaffer_envmap.io import read_envmap, read_image_array, write_envmap, write_png
    from gaffer_envmap.phrase import PhraseReading, read_phrase
    from gaffer_envmap.poses import (
        IDENTITY_LAYOUT_W2C,
        C2WOpenCV,
        W2CBlender,
        look_at_w2c_blender,
        orbit_w2c_blender,
    )
    from gaffer_envmap.procedural import procedural_envmap
    from gaffer_envmap.procedural_physical import physical_envmap
    from gaffer_envmap.resample import resize_conservative, resize_conservative_torch
    from gaffer_envmap.rotate import rotate_to_camera
    from gaffer_envmap.sanitize import SanitizeReport, sanitize
    from gaffer_envmap.sh import directionality, irradiance, project_sh, reconstruct_sh, sh_basis
    from gaffer_envmap.sky import SkyConfig, SunPosition, sky_envmap, sun_direction
    from gaffer_envmap.sources import (
        EnvmapSource,
        envmap_from_photo,
        envmap_from_text,
        envmap_sources,
        load_envmap_source,
    )
    from gaffer_envmap.stats import describe, first_moment, mean_light_direction, total_power
    from gaffer_envmap.studio import StudioConfig, StudioLight, studio_envmap
    from gaffer_envmap.sun_position import sun_position_at

__all__ = [
    "COMPAT_MODES",
    "CONVENTIONS",
    "IDENTITY_LAYOUT_W2C",
    "AugmentSpec",
    "C2WOpenCV",
    "Compat",
    "ConventionError",
    "EnvironmentMap",
    "EnvmapReadError",
    "EnvmapSource",
    "EnvmapSourceError",
    "EnvmapWriteError",
    "GafferEnvmapError",
    "GafferError",
    "HalfOverflowError",
    "LatLongConvention",
    "LightingEncoding",
    "MissingDependencyError",
    "NonFiniteError",
    "OutputPathError",
    "ParameterError",
    "PhraseReading",
    "PixelAlignment",
    "PoseError",
    "SanitizeReport",
    "ShapeError",
    "SkyConfig",
    "StudioConfig",
    "StudioLight",
    "SunPosition",
    "W2CBlender",
    "__version__",
    "augment_pool",
    "augment_specs",
    "bundled_hdri",
    "bundled_hdris",
    "chirality",
    "compat_problem",
    "convert_convention",
    "cube_to_latlong",
    "describe",
    "direction_grid",
    "direction_to_uv",
    "directionality",
    "encode_lighting",
    "envmap_from_photo",
    "envmap_from_text",
    "envmap_sources",
    "first_moment",
    "flip_horizontal",
    "get_convention",
    "hdr_encode",
    "irradiance",
    "is_compat",
    "latlong_to_cube",
    "ldr_encode",
    "load_envmap_source",
    "look_at_w2c_blender",
    "mean_light_direction",
    "orbit_w2c_blender",
    "physical_envmap",
    "procedural_envmap",
    "project_sh",
    "read_bundled_hdri",
    "read_envmap",
    "read_image_array",
    "read_phrase",
    "reconstruct_sh",
    "resize_conservative",
    "resize_conservative_torch",
    "rotate_to_camera",
    "row_solid_angle",
    "sanitize",
    "sh_basis",
    "sky_envmap",
    "solid_angle",
    "studio_envmap",
    "sun_direction",
    "sun_position_at",
    "to_center_alignment",
    "total_power",
    "uv_to_direction",
    "write_envmap",
    "write_png",
    "yaw_roll",
]
