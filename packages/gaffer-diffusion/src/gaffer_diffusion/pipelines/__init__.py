"""Inference pipelines: `RelightPipeline` (single-image relighting, paper §3.2)."""

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
    "RelightOutput",
    "RelightPipeline",
    "RuntimeConfig",
    "SamplingConfig",
]
