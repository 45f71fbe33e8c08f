"""Checkpoints of a running `train` call: where to resume from, writing one, restoring one.

The file layout and the atomic publish live in `checkpoint`; this module adds the accelerate side
(`save_state` / `load_state` on every process, the EMA weights, barriers).
"""

import logging
from pathlib import Path
from typing import Any

from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.errors import ResumeError

logger = logging.getLogger(__name__)


def prepare_checkpoint_root(acc: Any, ckpt_root: Path) -> None:
    """Create `ckpt_root` and remove the incomplete checkpoint folders of a killed run (main process),
    then wait for every process."""
    if acc.is_main_process:
        ckpt_root.mkdir(parents=True, exist_ok=True)
        removed = ckpt.remove_stale_temporaries(ckpt_root)
        if removed:
            logger.warning("removed %d incomplete checkpoint folder(s) of a killed run", removed)
    acc.wait_for_everyone()


def resume_point(resume: bool | str | Path, ckpt_root: Path) -> Path | None:
    """The checkpoint to resume from (None: a fresh start), as `train`'s `resume` says.

    Raises:
        ResumeError: `resume` True without a complete checkpoint, or a fresh start over checkpoints.
    """
    if resume is True:
        resume_from = ckpt.latest_checkpoint(ckpt_root)
        if resume_from is None:
            raise ResumeError(
                f"`--resume` was given but {ckpt_root} holds no complete checkpoint; start without "
                "`--resume`."
            )
        return resume_from
    if resume:
        return Path(resume)
    if ckpt.list_checkpoints(ckpt_root):
        raise ResumeError(
            f"{ckpt_root} already holds checkpoints; pass `--resume` to continue that run or choose "
            "another `output_dir`."
        )
    return None


def save_checkpoint(
    acc: Any, ckpt_root: Path, state: ckpt.TrainState, ema: EMAModel | None, keep: int
) -> Path:
    """Write the checkpoint of `state` (accelerate state of every process, EMA, `TrainState`), publish
    it atomically keeping the newest `keep`; returns its final folder."""
    tmp = ckpt.temporary_dir(ckpt_root, state.step)
    if acc.is_main_process:
        tmp.mkdir(parents=True, exist_ok=True)
    acc.wait_for_everyone()
    acc.save_state(str(tmp))
    # every process has written its files (its RNG state) before the folder is renamed; without
    # this barrier a slower rank re-created the temporary folder after the publish (issue 36)
    acc.wait_for_everyone()
    if acc.is_main_process:
        if ema is not None:
            ema.save(str(tmp / ckpt.EMA_NAME))
        ckpt.write_state(tmp, state)
        ckpt.publish(tmp, ckpt_root, state.step, keep)
    acc.wait_for_everyone()
    final = ckpt_root / ckpt.checkpoint_name(state.step)
    logger.info("saved checkpoint %s", final)
    return final


def restore_checkpoint(
    resume_from: Path,
    acc: Any,
    unet: Any,
    ema: EMAModel | None,
    ema_decay: float,
    *,
    per_step_samples: int | None = None,
) -> tuple[ckpt.TrainState, EMAModel | None]:
    """Load `resume_from` into the prepared UNet and optimiser (and `ema`); returns its `TrainState`
    and the EMA to use (restarted from the current weights when the checkpoint has none).

    `per_step_samples` (this run's global batch: batch x grad_accum x processes) is compared with the
    checkpoint's: the data stream continues where it stopped whatever the process count, but a
    different global batch groups it into other steps (a warning says so)."""
    state = ckpt.read_state(resume_from)
    acc.load_state(str(resume_from))
    if ema is not None:
        ema_file = resume_from / ckpt.EMA_NAME
        if ema_file.is_file():
            ema.load(str(ema_file))
        else:
            logger.warning(
                "%s has no EMA weights; the EMA restarts from the current weights", resume_from
            )
            ema = EMAModel(acc.unwrap_model(unet), ema_decay)
    train_cfg = state.config.get("train", {})
    saved = int(train_cfg.get("batch_size", 0)) * int(train_cfg.get("grad_accum", 1))
    saved *= state.world_size
    if state.world_size != acc.num_processes:
        logger.info(
            "resuming a %d-process run on %d processes", state.world_size, acc.num_processes
        )
    if per_step_samples is not None and saved and saved != per_step_samples:
        logger.warning(
            "resuming a run of %d samples per step with %d per step (batch_size x grad_accum x "
            "processes): the data stream continues, but the steps differ from the original run's",
            saved,
            per_step_samples,
        )
    logger.info("resumed from %s at step %d", resume_from, state.step)
    return state, ema
