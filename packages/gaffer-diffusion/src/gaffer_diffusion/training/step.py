"""One optimiser step of `train`: its micro-batches, the learning rate, the non-finite guard, the
AdamW and EMA updates, and the next `TrainState`."""

import dataclasses
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training.batch import TrainBatch
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.objective import ItemRandom, TrainingObjective

logger = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class StepOutcome:
    """What one optimiser step did.

    Attributes:
        state: the run's state after the step.
        loss: mean loss of its micro-batches (this process).
        applied: whether the weights were updated (False: non-finite loss or gradients, skipped).
        grad_norm: the gradient norm before clipping (NaN when the loss was not finite).
        lr: the learning rate of the step.
        wait: seconds spent waiting for the data loader.
        seconds: wall time of the step.
    """

    state: ckpt.TrainState
    loss: float
    applied: bool
    grad_norm: float
    lr: float
    wait: float
    seconds: float


@dataclass(frozen=True, kw_only=True)
class StepParts:
    """What every optimiser step of one `train` call uses (prepared by accelerate)."""

    cfg: TrainConfig
    acc: Any
    unet: torch.nn.Module
    unet_module: torch.nn.Module
    optimizer: torch.optim.Optimizer
    ema: EMAModel | None
    objective: TrainingObjective
    per_step_samples: int


def optimizer_step(
    parts: StepParts, state: ckpt.TrainState, batches: Iterator[TrainBatch]
) -> StepOutcome:
    """Run step `state.step`: `grad_accum` micro-batches, then the update unless any process saw a
    non-finite loss or gradient norm (the step is then skipped and counted)."""
    cfg, acc, unet, optimizer, o = (
        parts.cfg,
        parts.acc,
        parts.unet,
        parts.optimizer,
        parts.cfg.optim,
    )
    step = state.step
    t0 = time.perf_counter()
    wait = 0.0
    micro_losses: list[float] = []
    skipped_samples = 0
    for micro in range(cfg.train.grad_accum):
        tw = time.perf_counter()
        batch = next(batches)
        wait += time.perf_counter() - tw
        skipped_samples += batch.skipped
        # the global data-stream positions of this micro-batch's samples (KeySampler: process r reads
        # positions start + r, start + r + W, ...; batches take them in order)
        b, w = batch.batch_size, acc.num_processes
        first = state.samples_seen + acc.process_index + micro * b * w
        gen = ItemRandom.for_positions(cfg.train.seed, [first + j * w for j in range(b)])
        with acc.accumulate(unet):
            loss = parts.objective.loss(unet, batch, gen)
            acc.backward(loss)
        micro_losses.append(float(loss.detach()))
    lr = o.lr_at(step)
    for group in optimizer.param_groups:
        group["lr"] = lr
    step_loss = float(np.mean(micro_losses))
    # every process must take the same decision (DDP): reduce the "bad" flag
    bad = torch.tensor([0.0 if math.isfinite(step_loss) else 1.0], device=acc.device)
    bad = acc.reduce(bad, reduction="sum")
    grad_norm = float("nan")
    applied = False
    if float(bad.item()) == 0.0:
        max_norm = o.max_grad_norm if o.max_grad_norm is not None else float("inf")
        grad_norm = float(acc.clip_grad_norm_(unet.parameters(), max_norm))
        if math.isfinite(grad_norm) or acc.scaler is not None:
            optimizer.step()  # the fp16 scaler skips (and lowers its scale) on Inf grads
            applied = not acc.optimizer_step_was_skipped and math.isfinite(grad_norm)
    optimizer.zero_grad(set_to_none=True)
    if applied:
        if parts.ema is not None:
            parts.ema.update(parts.unet_module)
        consecutive = 0
        skipped_total = state.skipped_steps
    else:
        consecutive = state.consecutive_nonfinite + 1
        skipped_total = state.skipped_steps + 1
        logger.warning(
            "step %d: non-finite loss (%s) or gradient norm (%s); step skipped",
            step,
            step_loss,
            grad_norm,
        )
    new_state = dataclasses.replace(
        state,
        step=step + 1,
        samples_seen=state.samples_seen + parts.per_step_samples,
        skipped_steps=skipped_total,
        consecutive_nonfinite=consecutive,
        skipped_samples=state.skipped_samples + skipped_samples,
    )
    return StepOutcome(
        state=new_state,
        loss=step_loss,
        applied=applied,
        grad_norm=grad_norm,
        lr=lr,
        wait=wait,
        seconds=time.perf_counter() - t0,
    )
