"""gaffer-nerf: relight a TensoRF radiance field with the Neural Gaffer diffusion prior (paper §3.3).

Fit a TensoRF VM field to multi-view images (`fit_tensorf`), then relight it under a new environment
map in two stages (`relight_field`): Stage 1 fits the appearance to diffusion-relit training views,
Stage 2 refines it with the diffusion guidance loss. Score against ground truth under the target
lighting with `evaluate_field`.

`import gaffer_nerf` is light: each name below is imported from its module on first use (PEP 562),
so the command line checks its arguments before torch is imported (a refusal takes well under a
second).
"""

import importlib
from typing import TYPE_CHECKING, Any

from gaffer_nerf._version import __version__

if TYPE_CHECKING:
    from gaffer_nerf.cameras import Cameras, RayBundle
    from gaffer_nerf.checkpoint import load_field, save_field
    from gaffer_nerf.configs import (
        ABLATIONS,
        DiffusionSamplingConfig,
        EarlyStoppingConfig,
        FitConfig,
        GridSizingConfig,
        RankSelectionConfig,
        RelightConfig,
        SceneBoxConfig,
        Stage1Config,
        Stage2Config,
        TensoRFConfig,
        fit_preset,
        relight_preset,
    )
    from gaffer_nerf.data import (
        LightingInfo,
        MultiViewScene,
        ViewSet,
        load_lighting_envmap,
        read_gaffer_data_object,
        read_transforms_folder,
    )
    from gaffer_nerf.errors import (
        CameraError,
        CheckpointError,
        ConfigError,
        DatasetError,
        DatasetNotFoundError,
        GafferNerfError,
        MissingDependencyError,
        NonFiniteError,
        ShapeError,
    )
    from gaffer_nerf.evaluate import EmptyMaskWarning, evaluate_field, render_views
    from gaffer_nerf.fields import EmptyAlphaMaskWarning, TensoRFVM
    from gaffer_nerf.fit import (
        FitReport,
        FitResult,
        RankRung,
        RankSelectionReport,
        choose_rank_rung,
        fit_tensorf,
    )
    from gaffer_nerf.guidance import DiffusionGuide, PerceptualLoss, load_perceptual_loss, t_star
    from gaffer_nerf.relight import (
        NothingToRelightWarning,
        RelightReport,
        RelightResult,
        StageReport,
        relight_field,
    )
    from gaffer_nerf.rendering import (
        RenderOutput,
        SampleWeightCache,
        build_weight_cache,
        render_cached,
        render_rays,
    )
    from gaffer_nerf.sizing import GridSizing, choose_grid_sizing
    from gaffer_nerf.video import OrbitVideo, orbit_path, render_orbit

_EXPORTS = {
    "Cameras": "gaffer_nerf.cameras",
    "RayBundle": "gaffer_nerf.cameras",
    "load_field": "gaffer_nerf.checkpoint",
    "save_field": "gaffer_nerf.checkpoint",
    "ABLATIONS": "gaffer_nerf.configs",
    "DiffusionSamplingConfig": "gaffer_nerf.configs",
    "EarlyStoppingConfig": "gaffer_nerf.configs",
    "FitConfig": "gaffer_nerf.configs",
    "GridSizingConfig": "gaffer_nerf.configs",
    "RankSelectionConfig": "gaffer_nerf.configs",
    "RelightConfig": "gaffer_nerf.configs",
    "SceneBoxConfig": "gaffer_nerf.configs",
    "Stage1Config": "gaffer_nerf.configs",
    "Stage2Config": "gaffer_nerf.configs",
    "TensoRFConfig": "gaffer_nerf.configs",
    "fit_preset": "gaffer_nerf.configs",
    "relight_preset": "gaffer_nerf.configs",
    "LightingInfo": "gaffer_nerf.data",
    "MultiViewScene": "gaffer_nerf.data",
    "ViewSet": "gaffer_nerf.data",
    "load_lighting_envmap": "gaffer_nerf.data",
    "read_gaffer_data_object": "gaffer_nerf.data",
    "read_transforms_folder": "gaffer_nerf.data",
    "CameraError": "gaffer_nerf.errors",
    "CheckpointError": "gaffer_nerf.errors",
    "ConfigError": "gaffer_nerf.errors",
    "DatasetError": "gaffer_nerf.errors",
    "DatasetNotFoundError": "gaffer_nerf.errors",
    "GafferNerfError": "gaffer_nerf.errors",
    "MissingDependencyError": "gaffer_nerf.errors",
    "NonFiniteError": "gaffer_nerf.errors",
    "ShapeError": "gaffer_nerf.errors",
    "EmptyMaskWarning": "gaffer_nerf.evaluate",
    "evaluate_field": "gaffer_nerf.evaluate",
    "render_views": "gaffer_nerf.evaluate",
    "EmptyAlphaMaskWarning": "gaffer_nerf.fields",
    "TensoRFVM": "gaffer_nerf.fields",
    "FitReport": "gaffer_nerf.fit",
    "FitResult": "gaffer_nerf.fit",
    "RankRung": "gaffer_nerf.fit",
    "RankSelectionReport": "gaffer_nerf.fit",
    "choose_rank_rung": "gaffer_nerf.fit",
    "fit_tensorf": "gaffer_nerf.fit",
    "DiffusionGuide": "gaffer_nerf.guidance",
    "PerceptualLoss": "gaffer_nerf.guidance",
    "load_perceptual_loss": "gaffer_nerf.guidance",
    "t_star": "gaffer_nerf.guidance",
    "NothingToRelightWarning": "gaffer_nerf.relight",
    "RelightReport": "gaffer_nerf.relight",
    "RelightResult": "gaffer_nerf.relight",
    "StageReport": "gaffer_nerf.relight",
    "relight_field": "gaffer_nerf.relight",
    "RenderOutput": "gaffer_nerf.rendering",
    "SampleWeightCache": "gaffer_nerf.rendering",
    "build_weight_cache": "gaffer_nerf.rendering",
    "render_cached": "gaffer_nerf.rendering",
    "render_rays": "gaffer_nerf.rendering",
    "GridSizing": "gaffer_nerf.sizing",
    "choose_grid_sizing": "gaffer_nerf.sizing",
    "OrbitVideo": "gaffer_nerf.video",
    "orbit_path": "gaffer_nerf.video",
    "render_orbit": "gaffer_nerf.video",
}
"""Public name -> the module that defines it."""


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gaffer_nerf' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])


__all__ = [
    "ABLATIONS",
    "CameraError",
    "Cameras",
    "CheckpointError",
    "ConfigError",
    "DatasetError",
    "DatasetNotFoundError",
    "DiffusionGuide",
    "DiffusionSamplingConfig",
    "EarlyStoppingConfig",
    "EmptyAlphaMaskWarning",
    "EmptyMaskWarning",
    "FitConfig",
    "FitReport",
    "FitResult",
    "GafferNerfError",
    "GridSizing",
    "GridSizingConfig",
    "LightingInfo",
    "MissingDependencyError",
    "MultiViewScene",
    "NonFiniteError",
    "NothingToRelightWarning",
    "OrbitVideo",
    "PerceptualLoss",
    "RankRung",
    "RankSelectionConfig",
    "RankSelectionReport",
    "RayBundle",
    "RelightConfig",
    "RelightReport",
    "RelightResult",
    "RenderOutput",
    "SampleWeightCache",
    "SceneBoxConfig",
    "ShapeError",
    "Stage1Config",
    "Stage2Config",
    "StageReport",
    "TensoRFConfig",
    "TensoRFVM",
    "ViewSet",
    "__version__",
    "build_weight_cache",
    "choose_grid_sizing",
    "choose_rank_rung",
    "evaluate_field",
    "fit_preset",
    "fit_tensorf",
    "load_field",
    "load_lighting_envmap",
    "load_perceptual_loss",
    "orbit_path",
    "read_gaffer_data_object",
    "read_transforms_folder",
    "relight_field",
    "relight_preset",
    "render_cached",
    "render_orbit",
    "render_rays",
    "render_views",
    "save_field",
    "t_star",
]
