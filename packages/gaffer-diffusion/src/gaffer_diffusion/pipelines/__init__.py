"""Inference pipelines: `RelightPipeline` (single-image relighting, paper §3.2)."""

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
from gaffer_diffusion.pipelines.relight import RelightOutput, RelightPipeline

__all__ = [
    "AttentionBackend",
    "ConditionsBuilder",
    "DtypeName",
    "NonFinitePolicy",
    "RelightBatch",
    "RelightOutput",
    "RelightPipeline",
    "RuntimeConfig",
    "SamplingConfig",
    "relight_built_batches",
    "relight_in_batches",
]
