"""Scalar logging: always a JSON-lines file, plus TensorBoard when `tensorboard` is installed.

`OUTPUT/logs/train.jsonl` holds one JSON object per logged step (`{"step": 10, "loss": ...}`), appended
across resumed runs; validation rows carry `"kind": "validation"`. Only the main process writes.

Also what `train` reports while it runs: the scalar rows of each logging window (`LogWindow`,
`log_due`, `log_window`) and the progress bar (`open_progress`, `show_progress`).
"""

import importlib.util
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_diffusion.training.checkpoint import TrainState
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.step import StepOutcome

logger = logging.getLogger(__name__)


def tensorboard_available() -> bool:
    """True when `torch.utils.tensorboard` can write events (the `tensorboard` package is installed)."""
    return importlib.util.find_spec("tensorboard") is not None


class MetricsLogger:
    """Writes scalar rows to `train.jsonl` and, optionally, TensorBoard.

    Args:
        log_dir: folder for `train.jsonl` and the TensorBoard events (`tb/`).
        enabled: False on non-main processes (every call is then a no-op).
        tensorboard: also write TensorBoard events when available.
    """

    def __init__(self, log_dir: Path, *, enabled: bool = True, tensorboard: bool = True) -> None:
        self.enabled = enabled
        self.path = Path(log_dir) / "train.jsonl"
        self._tb: Any = None
        if not enabled:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if tensorboard and tensorboard_available():
            from torch.utils.tensorboard import SummaryWriter

            self._tb = SummaryWriter(log_dir=str(Path(log_dir) / "tb"))
        elif tensorboard:
            logger.info("tensorboard is not installed; logging to %s only", self.path)

    @property
    def tensorboard_enabled(self) -> bool:
        """Whether TensorBoard events are written."""
        return self._tb is not None

    def log(self, step: int, values: dict[str, float], *, kind: str = "train") -> None:
        """Append one row (`step`, `kind` and the values; non-finite values become null)."""
        if not self.enabled:
            return
        row: dict[str, Any] = {"step": int(step), "kind": kind}
        for k, v in values.items():
            fv = float(v)
            row[k] = fv if math.isfinite(fv) else None
        with self.path.open("a", encoding="utf-8") as f:
            f.write(json.dumps(row) + "\n")
        if self._tb is not None:
            for k, v in values.items():
                self._tb.add_scalar(f"{kind}/{k}", float(v), int(step))

    def log_image(self, step: int, tag: str, image_hwc: np.ndarray) -> None:
        """Add an `[H, W, 3]` uint8 image to TensorBoard (no-op without it)."""
        if self.enabled and self._tb is not None:
            self._tb.add_image(tag, image_hwc, int(step), dataformats="HWC")

    def close(self) -> None:
        """Flush and close TensorBoard."""
        if self._tb is not None:
            self._tb.close()
            self._tb = None


def read_log(path: str | Path, kind: str = "train") -> list[dict[str, Any]]:
    """Rows of `train.jsonl` of one kind, keeping for each step only the LAST row written (a resumed
    run re-logs the steps after its checkpoint)."""
    rows: dict[int, dict[str, Any]] = {}
    p = Path(path)
    if not p.is_file():
        return []
    for line in p.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        row = json.loads(line)
        if row.get("kind") == kind:
            rows[int(row["step"])] = row
    return [rows[s] for s in sorted(rows)]


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

    def row(self, outcome: StepOutcome, state: TrainState) -> dict[str, float]:
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
