"""gaffer-diffusion: the Neural Gaffer relighting diffusion model (NeurIPS 2024), built on diffusers.

Public API: configs and presets, model construction, conditioning, the relighting pipeline and samplers,
loaders for the authors' checkpoint / Zero123-XL / our own format, and evaluation metrics.

The names are loaded lazily (PEP 562), so `import gaffer_diffusion.cli` or `gaffer_diffusion.errors`
does not import torch or diffusers: the command line checks its arguments before it loads them, so
a refusal takes well under a second.
"""

import importlib
from typing import TYPE_CHECKING, Any

from gaffer_diffusion._version import __version__

_EXPORTS: dict[str, str] = {
    "CheckpointMismatchError": "errors",
    "CheckpointNotFoundError": "errors",
    "ConfigError": "errors",
    "DefaultSampling": "suggested",
    "EncodedConditions": "conditioning",
    "GafferDiffusionError": "errors",
    "ImageEncoderConfig": "configs",
    "InputValueError": "errors",
    "LatentMode": "conditioning",
    "LightingMaps": "conditioning",
    "LoadedModel": "pipelines",
    "MetricUnavailableError": "errors",
    "MissingDependencyError": "errors",
    "ModelConfig": "configs",
    "NeuralGafferModel": "models",
    "NeuralGafferPipeline": "pipelines.neural_gaffer",
    "NeuralGafferPipelineOutput": "pipelines.neural_gaffer",
    "NonFiniteOutputError": "errors",
    "PAPER_SAMPLING": "suggested",
    "PRESETS": "configs",
    "RelightOutput": "pipelines",
    "RelightPipeline": "pipelines",
    "RelightingConditions": "conditioning",
    "RuntimeConfig": "pipelines",
    "SCHEDULERS": "schedulers",
    "SamplingConfig": "sampling_config",
    "SchedulerConfig": "configs",
    "ShapeError": "errors",
    "UNetConfig": "configs",
    "VAEConfig": "configs",
    "build_model": "models",
    "clip_preprocess": "conditioning",
    "encode_conditions": "conditioning",
    "expand_conv_in": "models",
    "get_preset": "configs",
    "latent_mode_for": "suggested",
    "lighting_from_envmap": "conditioning",
    "load_pipeline": "pipelines",
    "make_scheduler": "schedulers",
}


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gaffer_diffusion' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"gaffer_diffusion.{module}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(__all__)


if TYPE_CHECKING:  # static re-exports for type checkers and IDEs
    from gaffer_diffusion.conditioning import (
        EncodedConditions,
        LatentMode,
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
    from gaffer_diffusion.pipelines import (
        LoadedModel,
        RelightOutput,
        RelightPipeline,
        RuntimeConfig,
        load_pipeline,
    )
    from gaffer_diffusion.pipelines.neural_gaffer import (
        NeuralGafferPipeline,
        NeuralGafferPipelineOutput,
    )
    from gaffer_diffusion.sampling_config import SamplingConfig
    from gaffer_diffusion.schedulers import SCHEDULERS, make_scheduler
    from gaffer_diffusion.suggested import PAPER_SAMPLING, DefaultSampling, latent_mode_for


__all__ = [
    "PAPER_SAMPLING",
    "PRESETS",
    "SCHEDULERS",
    "CheckpointMismatchError",
    "CheckpointNotFoundError",
    "ConfigError",
    "DefaultSampling",
    "EncodedConditions",
    "GafferDiffusionError",
    "ImageEncoderConfig",
    "InputValueError",
    "LatentMode",
    "LightingMaps",
    "LoadedModel",
    "MetricUnavailableError",
    "MissingDependencyError",
    "ModelConfig",
    "NeuralGafferModel",
    "NeuralGafferPipeline",
    "NeuralGafferPipelineOutput",
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
    "latent_mode_for",
    "lighting_from_envmap",
    "load_pipeline",
    "make_scheduler",
]
