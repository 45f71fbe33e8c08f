"""Inference pipelines: `RelightPipeline` (single-image relighting, paper §3.2) and `load_pipeline`."""

from gaffer_diffusion.pipelines.batched import (
    ConditionsBuilder,
    RelightBatch,
    relight_built_batches,
    relight_in_batches,
)
from gaffer_diffusion.pipelines.config import (
    AttentionBackend,
    DtypeName,
    NonFinitePolicy,
    RuntimeConfig,
    SamplingConfig,
)
from gaffer_diffusion.pipelines.load import LoadedModel, load_pipeline
from gaffer_diffusion.pipelines.relight import RelightOutput, RelightPipeline, default_sampling_for

__all__ = [
    "AttentionBackend",
    "ConditionsBuilder",
    "DtypeName",
    "LoadedModel",
    "NonFinitePolicy",
    "RelightBatch",
    "RelightOutput",
    "RelightPipeline",
    "RuntimeConfig",
    "SamplingConfig",
    "default_sampling_for",
    "load_pipeline",
    "relight_built_batches",
    "relight_in_batches",
]
