"""gaffer-nerf: relight a TensoRF radiance field with the Neural Gaffer diffusion prior (paper §3.3).

Fit a TensoRF VM field to multi-view images (`fit_tensorf`), then relight it under a new environment
map in two stages (`relight_field`): Stage 1 fits the appearance to diffusion-relit training views,
Stage 2 refines it with the diffusion guidance loss. Score against ground truth under the target
lighting with `evaluate_field`.
"""

from gaffer_nerf._version import __version__
from gaffer_nerf.cameras import Cameras, RayBundle
from gaffer_nerf.checkpoint import load_field, save_field
from gaffer_nerf.configs import (
    ABLATIONS,
    DiffusionSamplingConfig,
    EarlyStoppingConfig,
    FitConfig,
    GridSizingConfig,
    ModelSampling,
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
from gaffer_nerf.video import OrbitVideo, orbit_path, render_orbit, write_gif

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
    "ModelSampling",
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
    "write_gif",
]
