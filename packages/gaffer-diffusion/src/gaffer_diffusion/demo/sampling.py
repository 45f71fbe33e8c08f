"""Sampling: every job through batched pipeline calls, one seed for all."""

import logging
import time
from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.lightings import _Lighting
from gaffer_diffusion.evaluation import quantize_8bit
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig

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
    for lo in range(0, len(jobs), config.batch_size):
        chunk = jobs[lo : lo + config.batch_size]
        cond = RelightingConditions(
            image=image.expand(len(chunk), -1, -1, -1),
            lighting=LightingMaps(
                ldr=torch.cat([j.maps.ldr for j in chunk]),
                hdr=torch.cat([j.maps.hdr for j in chunk]),
            ),
            mask=None if mask is None else mask.expand(len(chunk), -1, -1, -1),
        )
        t0 = time.perf_counter()
        # one seed for every image: a result does not depend on its batch, and the turntable's
        # noise stays still while its light moves (less flicker)
        result = pipe(cond, sampling, seeds=[config.seed] * len(chunk))
        seconds.append(time.perf_counter() - t0)
        out.append(quantize_8bit(result.images.float().cpu()))
        done = lo + len(chunk)
        logger.info("relit %d/%d images (%.2f s for this batch)", done, len(jobs), seconds[-1])
        if on_batch is not None:
            on_batch(done, len(jobs))
    return torch.cat(out), seconds
