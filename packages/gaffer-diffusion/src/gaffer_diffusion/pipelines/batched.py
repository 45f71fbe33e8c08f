"""`relight_in_batches`: relight N items in pipeline calls of at most `batch_size` items.

The one batching loop of the library (CLI `relight` and its photo x map grid, the demo, the app,
evaluation, validation during training): `relight_built_batches` is the loop, over a callable that
builds the `RelightingConditions` of items `[start, stop)` when their call comes (callers that read
their inputs lazily, per batch); `relight_in_batches` is that loop over tensors already in memory: a
shared input image (batch 1) is expanded to each chunk, per-item inputs are sliced, the lighting is
always per item. The seeds are one for every item or one per item, so a result does not depend on the
chunk it landed in.
"""

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
from gaffer_diffusion.pipelines.config import SamplingConfig
from gaffer_diffusion.pipelines.relight import RelightOutput, RelightPipeline


@dataclass(frozen=True, kw_only=True)
class RelightBatch:
    """One pipeline call of `relight_in_batches`: items `start..stop-1` and their output."""

    start: int
    stop: int
    output: RelightOutput


def _chunk(x: Tensor, lo: int, hi: int, device: torch.device | str | None) -> Tensor:
    part = x.expand(hi - lo, -1, -1, -1) if x.shape[0] == 1 else x[lo:hi]
    return part if device is None else part.to(device)


def relight_in_batches(
    pipe: RelightPipeline,
    image: Tensor,
    lighting: LightingMaps,
    sampling: SamplingConfig,
    *,
    seeds: int | Sequence[int],
    batch_size: int,
    mask: Tensor | None = None,
    device: torch.device | str | None = None,
) -> Iterator[RelightBatch]:
    """Relight the `N = lighting.batch_size` items, `batch_size` per pipeline call, in order.

    Args:
        pipe: the pipeline.
        image: `[1, 3, H, W]` (the same input for every item) or `[N, 3, H, W]`.
        lighting: `[N, 3, H, W]` target lighting maps.
        sampling: the sampling settings of every call.
        seeds: one seed for every item, or N seeds (item i is sampled with `seeds[i]`).
        batch_size: the most items per call.
        mask: None (the model's full frame), or `[1 or N, 1, H, W]` as `image`.
        device: move each chunk's image and mask there (None: as they are).

    Yields:
        A `RelightBatch` per call.

    Example:
        >>> from gaffer_diffusion import build_model, get_preset
        >>> pipe = RelightPipeline(build_model(get_preset("tiny")))
        >>> x = torch.rand(1, 3, 64, 64)
        >>> maps = LightingMaps(ldr=torch.rand(3, 3, 64, 64), hdr=torch.rand(3, 3, 64, 64))
        >>> cfg = SamplingConfig(num_inference_steps=1)
        >>> [(b.start, b.stop) for b in relight_in_batches(pipe, x, maps, cfg, seeds=0, batch_size=2)]
        [(0, 2), (2, 3)]
    """

    def build(lo: int, hi: int) -> RelightingConditions:
        return RelightingConditions(
            image=_chunk(image, lo, hi, device),
            lighting=LightingMaps(ldr=lighting.ldr[lo:hi], hdr=lighting.hdr[lo:hi]),
            mask=None if mask is None else _chunk(mask, lo, hi, device),
        )

    return relight_built_batches(
        pipe, lighting.batch_size, build, sampling, seeds=seeds, batch_size=batch_size
    )


ConditionsBuilder = Callable[[int, int], RelightingConditions]
"""`build(start, stop)`: the conditions of items `start..stop-1` (batch `stop - start`)."""


def relight_built_batches(
    pipe: RelightPipeline,
    count: int,
    build: ConditionsBuilder,
    sampling: SamplingConfig,
    *,
    seeds: int | Sequence[int],
    batch_size: int,
) -> Iterator[RelightBatch]:
    """Relight `count` items, `batch_size` per pipeline call, in order, building each call's
    conditions with `build(start, stop)` just before the call (inputs read lazily, per batch).

    Args:
        pipe: the pipeline.
        count: N, the number of items.
        build: returns the `RelightingConditions` of items `[start, stop)`.
        sampling: the sampling settings of every call.
        seeds: one seed for every item, or N seeds (item i is sampled with `seeds[i]`).
        batch_size: the most items per call.

    Yields:
        A `RelightBatch` per call.

    Example:
        >>> from gaffer_diffusion import build_model, get_preset
        >>> pipe = RelightPipeline(build_model(get_preset("tiny")))
        >>> def build(lo, hi):
        ...     maps = LightingMaps(ldr=torch.rand(hi - lo, 3, 64, 64), hdr=torch.rand(hi - lo, 3, 64, 64))
        ...     return RelightingConditions(image=torch.rand(hi - lo, 3, 64, 64), lighting=maps)
        >>> cfg = SamplingConfig(num_inference_steps=1)
        >>> [(b.start, b.stop) for b in relight_built_batches(pipe, 3, build, cfg, seeds=0, batch_size=2)]
        [(0, 2), (2, 3)]
    """
    for lo in range(0, count, batch_size):
        hi = min(lo + batch_size, count)
        cond = build(lo, hi)
        chunk_seeds = [seeds] * (hi - lo) if isinstance(seeds, int) else list(seeds[lo:hi])
        yield RelightBatch(start=lo, stop=hi, output=pipe(cond, sampling, seeds=chunk_seeds))
