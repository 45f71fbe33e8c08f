"""Inference pipelines: `RelightPipeline` (single-image relighting, paper §3.2)."""

from gaffer_diffusion.pipelines.batched import RelightBatch, relight_in_batches
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
    "DtypeName",
    "NonFinitePolicy",
    "RelightBatch",
    "RelightOutput",
    "RelightPipeline",
    "RuntimeConfig",
    "SamplingConfig",
    "relight_in_batches",
]
