"""gaffer-diffusion: the Neural Gaffer relighting diffusion model (NeurIPS 2024), built on diffusers.

Public API: configs and presets, model construction, conditioning, the relighting pipeline and samplers,
loaders for the authors' checkpoint / Zero123-XL / our own format, and evaluation metrics.
"""

from gaffer_diffusion._version import __version__
from gaffer_diffusion.conditioning import (
    EncodedConditions,
    LightingMaps,
    RelightingConditions,
    clip_preprocess,
    encode_conditions,
    lighting_from_envmap,
)
from gaffer_diffusion.configs import (
    PRESETS,
    ImageEncoderConfig,
    ModelConfig,
    SchedulerConfig,
    UNetConfig,
    VAEConfig,
    get_preset,
)
from gaffer_diffusion.errors import (
    CheckpointMismatchError,
    CheckpointNotFoundError,
    ConfigError,
    GafferDiffusionError,
    InputValueError,
    MetricUnavailableError,
    MissingDependencyError,
    NonFiniteOutputError,
    ShapeError,
)
from gaffer_diffusion.models import NeuralGafferModel, build_model, expand_conv_in
from gaffer_diffusion.pipelines import RelightOutput, RelightPipeline, RuntimeConfig, SamplingConfig
from gaffer_diffusion.schedulers import SCHEDULERS, make_scheduler

__all__ = [
    "PRESETS",
    "SCHEDULERS",
    "CheckpointMismatchError",
    "CheckpointNotFoundError",
    "ConfigError",
    "EncodedConditions",
    "GafferDiffusionError",
    "ImageEncoderConfig",
    "InputValueError",
    "LightingMaps",
    "MetricUnavailableError",
    "MissingDependencyError",
    "ModelConfig",
    "NeuralGafferModel",
    "NonFiniteOutputError",
    "RelightOutput",
    "RelightPipeline",
    "RelightingConditions",
    "RuntimeConfig",
    "SamplingConfig",
    "SchedulerConfig",
    "ShapeError",
    "UNetConfig",
    "VAEConfig",
    "__version__",
    "build_model",
    "clip_preprocess",
    "encode_conditions",
    "expand_conv_in",
    "get_preset",
    "lighting_from_envmap",
    "make_scheduler",
]
