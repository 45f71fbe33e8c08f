"""Sampling: every job through batched pipeline calls, one seed for all."""

import logging
import time
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from gaffer_diffusion.conditioning import LightingMaps
from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.lightings import _Lighting
from gaffer_diffusion.evaluation import quantize_8bit
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig, relight_in_batches

logger = logging.getLogger("gaffer_diffusion.demo")  # the name log lines carried before the split


def _sample(
    pipe: RelightPipeline,
    image: Tensor,
    mask: Tensor | None,
    jobs: Sequence[_Lighting],
    sampling: SamplingConfig,
    config: DemoConfig,
    on_batch: Callable[[int, int], None] | None = None,
) -> tuple[Tensor, list[float]]:
    """`[N, 3, S, S]` 8-bit-quantised relit images, and the wall time of every batch."""
    out: list[Tensor] = []
    seconds: list[float] = []
    lighting = LightingMaps(
        ldr=torch.cat([j.maps.ldr for j in jobs]), hdr=torch.cat([j.maps.hdr for j in jobs])
    )
    # one seed for every image: a result does not depend on its batch, and the turntable's
    # noise stays still while its light moves (less flicker)
    batches = relight_in_batches(
        pipe, image, lighting, sampling, seeds=config.seed, batch_size=config.batch_size, mask=mask
    )
    t0 = time.perf_counter()
    for batch in batches:
        seconds.append(time.perf_counter() - t0)
        out.append(quantize_8bit(batch.output.images.float().cpu()))
        done = batch.stop
        logger.info("relit %d/%d images (%.2f s for this batch)", done, len(jobs), seconds[-1])
        if on_batch is not None:
            on_batch(done, len(jobs))
        t0 = time.perf_counter()
    return torch.cat(out), seconds
