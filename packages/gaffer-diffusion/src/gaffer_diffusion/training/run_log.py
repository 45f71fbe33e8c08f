"""What `train` reports while it runs: the scalar rows of each logging window, the progress bar."""

import logging
from dataclasses import dataclass
from typing import Any

from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.step import StepOutcome
from gaffer_diffusion.training.tracking import MetricsLogger

logger = logging.getLogger(__name__)


@dataclass
class LogWindow:
    """Sums over the optimiser steps since the last logged row."""

    loss: float = 0.0
    applied: int = 0
    wait: float = 0.0
    seconds: float = 0.0
    samples: int = 0

    def add(self, outcome: StepOutcome, samples: int) -> None:
        """Count one step (the loss of applied steps only)."""
        self.loss += outcome.loss if outcome.applied else 0.0
        self.applied += 1 if outcome.applied else 0
        self.wait += outcome.wait
        self.seconds += outcome.seconds
        self.samples += samples

    def row(self, outcome: StepOutcome, state: ckpt.TrainState) -> dict[str, float]:
        """The logged scalars: window means, and the last step's learning rate and gradient norm."""
        return {
            "loss": self.loss / max(self.applied, 1),
            "lr": outcome.lr,
            "samples_per_s": self.samples / max(self.seconds, 1e-9),
            "data_wait_share": self.wait / max(self.seconds, 1e-9),
            "grad_norm": outcome.grad_norm,
            "skipped_steps": state.skipped_steps,
            "skipped_samples": state.skipped_samples,
        }


def log_due(cfg: TrainConfig, step: int) -> bool:
    """Whether a row is logged after `step` (every `logging.every_steps` steps and at the end)."""
    return step % cfg.logging.every_steps == 0 or step == cfg.train.max_steps


def log_window(log: MetricsLogger, window: LogWindow, outcome: StepOutcome) -> LogWindow:
    """Log the window's row at `outcome.state.step`; returns a fresh window."""
    state = outcome.state
    log.log(state.step, window.row(outcome, state))
    if state.skipped_samples:
        logger.info("%d unreadable samples skipped so far", state.skipped_samples)
    return LogWindow()


def open_progress(cfg: TrainConfig, is_main_process: bool, initial: int) -> Any:
    """A tqdm bar over the steps (main process, `logging.progress_bar`), or None."""
    if not (cfg.logging.progress_bar and is_main_process):
        return None
    from tqdm.auto import tqdm

    return tqdm(total=cfg.train.max_steps, initial=initial, desc="train", unit="step")


def show_progress(progress: Any, outcome: StepOutcome) -> None:
    """Advance the bar by one step, showing its loss and learning rate."""
    if progress is not None:
        progress.update(1)
        progress.set_postfix(loss=f"{outcome.loss:.4f}", lr=f"{outcome.lr:.2e}")
