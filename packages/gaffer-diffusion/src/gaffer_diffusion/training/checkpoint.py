"""Crash-safe training checkpoints: written to a temporary folder, fsynced, then renamed.

Layout of `OUTPUT/checkpoints/checkpoint-00001000/`:

- accelerate's `save_state` files: the UNet (`model.safetensors`), the optimiser, the fp16 grad scaler
  and RNG states (for DeepSpeed/FSDP, accelerate's own sharded layout);
- `ema_unet.safetensors`: the EMA weights (see `EMAModel`);
- `train_state.json`: step, samples consumed, counters and the full training config.

A checkpoint folder only ever appears complete: everything is written into `.tmp-checkpoint-*`, every
file is fsynced, and one `os.replace` publishes it. `kill -9` at any moment leaves either the previous
checkpoints untouched or a stale temporary folder, which the next run deletes. Old checkpoints are
deleted only after a newer one is complete.

The folder layout and the atomic publish come first; then the accelerate side of a running `train`
call (`prepare_checkpoint_root`, `resume_point`, `save_checkpoint`, `restore_checkpoint`: accelerate's
`save_state` / `load_state` on every process, the EMA weights, barriers).
"""

import dataclasses
import datetime
import json
import logging
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gaffer_diffusion._schema_header import check_schema_header
from gaffer_diffusion._version import __version__
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.errors import ResumeError

logger = logging.getLogger(__name__)

STATE_NAME = "train_state.json"
EMA_NAME = "ema_unet.safetensors"
STATE_SCHEMA = "gaffer.train_checkpoint"
STATE_SCHEMA_VERSION = "1.0"
_NAME = re.compile(r"^checkpoint-(\d+)$")
_TMP_PREFIX = ".tmp-checkpoint-"


@dataclass(frozen=True, kw_only=True)
class TrainState:
    """Counters of a run, saved in every checkpoint.

    Attributes:
        step: optimiser steps taken.
        samples_seen: samples consumed over all processes (the data stream's resume position).
        skipped_steps: steps skipped for NaN/Inf loss or gradients.
        consecutive_nonfinite: the current run of skipped steps.
        skipped_samples: unreadable samples replaced by the data loader.
        world_size: processes the run used (resuming with another count changes the data order).
        config: the training config, as JSON.
    """

    step: int
    samples_seen: int
    skipped_steps: int = 0
    consecutive_nonfinite: int = 0
    skipped_samples: int = 0
    world_size: int = 1
    config: dict[str, Any] = dataclasses.field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """The `train_state.json` body (with schema header)."""
        return {
            "schema": STATE_SCHEMA,
            "schema_version": STATE_SCHEMA_VERSION,
            "producer": {"package": "gaffer-diffusion", "version": __version__},
            "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            **dataclasses.asdict(self),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any], where: str) -> "TrainState":
        """Parse `to_json` output.

        Raises:
            ResumeError: foreign schema, other MAJOR version or missing fields.
        """
        check_schema_header(
            data, schema=STATE_SCHEMA, version=STATE_SCHEMA_VERSION, where=where, error=ResumeError
        )
        names = {f.name for f in dataclasses.fields(cls)}
        try:
            return cls(**{k: v for k, v in data.items() if k in names})
        except TypeError as exc:
            raise ResumeError(f"{where} is malformed: {exc}") from exc


def checkpoint_name(step: int) -> str:
    """`checkpoint-00001000` (zero-padded so names sort by step)."""
    return f"checkpoint-{step:08d}"


def list_checkpoints(root: str | Path) -> list[tuple[int, Path]]:
    """Complete checkpoints under `root` as `(step, folder)`, oldest first."""
    root = Path(root)
    if not root.is_dir():
        return []
    out = []
    for p in root.iterdir():
        m = _NAME.match(p.name)
        if m and p.is_dir() and (p / STATE_NAME).is_file():
            out.append((int(m.group(1)), p))
    return sorted(out)


def latest_checkpoint(root: str | Path) -> Path | None:
    """The newest complete checkpoint folder, or None."""
    found = list_checkpoints(root)
    return found[-1][1] if found else None


def remove_stale_temporaries(root: str | Path) -> int:
    """Delete `.tmp-checkpoint-*` folders left by killed writers; returns how many."""
    root = Path(root)
    if not root.is_dir():
        return 0
    stale = [p for p in root.iterdir() if p.name.startswith(_TMP_PREFIX)]
    for p in stale:
        shutil.rmtree(p, ignore_errors=True)
    return len(stale)


def temporary_dir(root: str | Path, step: int) -> Path:
    """The folder a checkpoint of `step` is written into before `publish`."""
    return Path(root) / f"{_TMP_PREFIX}{step:08d}"


def _fsync_tree(folder: Path) -> None:
    for dirpath, _, files in os.walk(folder):
        for name in files:
            fd = os.open(os.path.join(dirpath, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        fd = os.open(dirpath, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_state(folder: Path, state: TrainState) -> None:
    """Write `train_state.json` into a (temporary) checkpoint folder."""
    (folder / STATE_NAME).write_text(json.dumps(state.to_json(), indent=2), encoding="utf-8")


def publish(tmp: Path, root: str | Path, step: int, keep: int) -> Path:
    """fsync `tmp`, rename it to `checkpoint-{step}`, then delete all but the newest `keep`.

    Returns:
        The published folder.
    """
    root = Path(root)
    final = root / checkpoint_name(step)
    _fsync_tree(tmp)
    if final.exists():  # the same step saved again (e.g. SIGTERM right after a periodic save)
        old = root / f"{_TMP_PREFIX}old-{step:08d}"
        shutil.rmtree(old, ignore_errors=True)
        os.replace(final, old)
        os.replace(tmp, final)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, final)
    fd = os.open(root, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    for _, old_ckpt in list_checkpoints(root)[:-keep]:
        shutil.rmtree(old_ckpt, ignore_errors=True)
        logger.info("deleted old checkpoint %s", old_ckpt)
    return final


def read_state(folder: str | Path) -> TrainState:
    """The `TrainState` of a checkpoint folder.

    Raises:
        ResumeError: the folder is not a complete checkpoint.
    """
    path = Path(folder) / STATE_NAME
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise ResumeError(
            f"{path} is missing or unreadable ({exc}); pass a complete `checkpoint-*` folder."
        ) from exc
    return TrainState.from_json(data, str(path))


def prepare_checkpoint_root(acc: Any, ckpt_root: Path) -> None:
    """Create `ckpt_root` and remove the incomplete checkpoint folders of a killed run (main process),
    then wait for every process."""
    if acc.is_main_process:
        ckpt_root.mkdir(parents=True, exist_ok=True)
        removed = remove_stale_temporaries(ckpt_root)
        if removed:
            logger.warning("removed %d incomplete checkpoint folder(s) of a killed run", removed)
    acc.wait_for_everyone()


def resume_point(resume: bool | str | Path, ckpt_root: Path) -> Path | None:
    """The checkpoint to resume from (None: a fresh start), as `train`'s `resume` says.

    Raises:
        ResumeError: `resume` True without a complete checkpoint, or a fresh start over checkpoints.
    """
    if resume is True:
        resume_from = latest_checkpoint(ckpt_root)
        if resume_from is None:
            raise ResumeError(
                f"`--resume` was given but {ckpt_root} holds no complete checkpoint; start without "
                "`--resume`."
            )
        return resume_from
    if resume:
        return Path(resume)
    if list_checkpoints(ckpt_root):
        raise ResumeError(
            f"{ckpt_root} already holds checkpoints; pass `--resume` to continue that run or choose "
            "another `output_dir`."
        )
    return None


def save_checkpoint(
    acc: Any, ckpt_root: Path, state: TrainState, ema: EMAModel | None, keep: int
) -> Path:
    """Write the checkpoint of `state` (accelerate state of every process, EMA, `TrainState`), publish
    it atomically keeping the newest `keep`; returns its final folder."""
    tmp = temporary_dir(ckpt_root, state.step)
    if acc.is_main_process:
        tmp.mkdir(parents=True, exist_ok=True)
    acc.wait_for_everyone()
    acc.save_state(str(tmp))
    # every process has written its files (its RNG state) before the folder is renamed; without
    # this barrier a slower rank re-created the temporary folder after the publish
    acc.wait_for_everyone()
    if acc.is_main_process:
        if ema is not None:
            ema.save(str(tmp / EMA_NAME))
        write_state(tmp, state)
        publish(tmp, ckpt_root, state.step, keep)
    acc.wait_for_everyone()
    final = ckpt_root / checkpoint_name(state.step)
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
) -> tuple[TrainState, EMAModel | None]:
    """Load `resume_from` into the prepared UNet and optimiser (and `ema`); returns its `TrainState`
    and the EMA to use (restarted from the current weights when the checkpoint has none).

    `per_step_samples` (this run's global batch: batch x grad_accum x processes) is compared with the
    checkpoint's: the data stream continues where it stopped whatever the process count, but a
    different global batch groups it into other steps (a warning says so)."""
    state = read_state(resume_from)
    acc.load_state(str(resume_from))
    if ema is not None:
        ema_file = resume_from / EMA_NAME
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
