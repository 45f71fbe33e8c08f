"""The training loop on accelerate (official implementation §3).

One optimiser step (per process, per micro-batch):

1. the data loader yields B samples, each an input view and T target views with their lighting;
2. the target lightings are rotated into the view's camera frame and split into E_L / E_H by
   gaffer-envmap, batched on the training device (no PNG round trip); items of a converted authors'
   split bring their pre-encoded E_L / E_H PNGs instead, used as they are;
3. one VAE call encodes the B inputs and the T*B HDR maps, LDR maps and targets; CLIP embeds the inputs;
4. Neural Gaffer §3.2: z_t = sqrt(abar_t) z_0 + sqrt(1 - abar_t) eps with t ~ U{0..999}, the UNet sees
   `[z_t, E(x), E(E_H), E(E_L)]` and the CLIP context; loss = ||eps - eps_theta||^2;
5. CFG dropout (InstructPix2Pix scheme, p = 0.05, one uniform r per UNet item): r < 2p zeroes the CLIP
   embedding, p <= r < 3p zeroes the three conditioning latents;
6. AdamW step (only the UNet trains), EMA update.

The data order is a function of (seed, position in the run's data stream) and each sample's randomness
(noise, timestep, CFG dropout, flips) of (seed, its position) too (`objective.ItemRandom`), so `--resume`
continues with exactly the loss curve of an uninterrupted run, and N processes of batch B train as one
process of batch N*B (up to float rounding; also across a resume that changes the process count).
Several processes on a CPU-only machine join one gloo group (`torchrun --nproc_per_node N` or
`accelerate launch --multi_gpu --num_processes N`; `accelerate launch --cpu` starts only one).

Non-finite loss or gradients never reach the weights: the step is skipped and counted; after
`train.max_consecutive_nonfinite` skipped steps in a row a checkpoint is written and
`TrainingDivergedError` raised.

`train` orchestrates; each part lives in its own module: `objective` (the loss of one micro-batch),
`step` (one optimiser step), `checkpoint` (the folders; resume point, save, restore), `tracking`
(the metrics log, logged rows, progress bar), `validation` (validation during training), `sigterm`.
Setting up the accelerator, the networks and the data stays here.
"""

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import torch

from gaffer_diffusion.configs import get_preset
from gaffer_diffusion.errors import ConfigError, MissingDependencyError
from gaffer_diffusion.models.build import build_model
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training.checkpoint import (
    prepare_checkpoint_root,
    restore_checkpoint,
    resume_point,
    save_checkpoint,
)
from gaffer_diffusion.training.config import ModelSource, TrainConfig
from gaffer_diffusion.training.dataset import (
    KeySampler,
    RelightTrainDataset,
    TrainBatch,
    collate_items,
    split_object_ids,
)
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.errors import TrainingDivergedError
from gaffer_diffusion.training.objective import TrainingObjective, cfg_dropout_masks, diffusion_loss
from gaffer_diffusion.training.objective import _mirror_views as _mirror_views
from gaffer_diffusion.training.objective import _prediction_target as _prediction_target
from gaffer_diffusion.training.objects import check_lighting_compat, dataset_object_ids
from gaffer_diffusion.training.sigterm import SigtermFlag
from gaffer_diffusion.training.step import StepParts, optimizer_step
from gaffer_diffusion.training.tracking import (
    LogWindow,
    MetricsLogger,
    log_due,
    log_window,
    open_progress,
    show_progress,
)
from gaffer_diffusion.training.validation import (
    TrainingValidation,
    ValidationResult,
    ValidationSet,
    build_validation_set,
    sampling_model,
)

__all__ = [
    "StepCallback",
    "StopReason",
    "TrainResult",
    "build_training_model",
    "cfg_dropout_masks",
    "cpu_has_bf16",
    "diffusion_loss",
    "load_checkpoint_model",
    "train",
]

logger = logging.getLogger(__name__)

# the objective's former name here (tests patch `_Trainer.loss`)
_Trainer = TrainingObjective

StopReason = Literal["max_steps", "time_limit", "sigterm"]
StepCallback = Callable[[int, float], None]


@dataclass(frozen=True, kw_only=True)
class TrainResult:
    """What a `train` call did.

    Attributes:
        step: optimiser steps completed in total (including those before a resume).
        start_step: the step this call started from (0, or the resumed checkpoint's).
        losses: mean loss of every optimiser step of this call (this process), NaN for skipped steps.
        stop_reason: "max_steps", "time_limit" or "sigterm".
        checkpoint: the last checkpoint written, or None.
        final_model: `output_dir/final` (EMA weights, our model format) when training finished.
        skipped_steps: steps skipped for NaN/Inf (whole run).
        skipped_samples: unreadable samples replaced by the data loader (whole run).
        validations: the validations run by this call.
        seconds: wall time of this call.
        end_training_errors: 1 when accelerate's `end_training()` (tracker flush, process-group
            teardown) failed after the results were saved (logged as a warning), else 0.
    """

    step: int
    start_step: int
    losses: tuple[float, ...]
    stop_reason: StopReason
    checkpoint: Path | None
    final_model: Path | None
    skipped_steps: int
    skipped_samples: int
    validations: tuple[ValidationResult, ...]
    seconds: float
    end_training_errors: int = 0


def build_training_model(source: ModelSource) -> NeuralGafferModel:
    """The networks named by `source` (float32, CPU).

    Raises:
        ConfigError: a preset resolution that is not a multiple of 8.
        CheckpointNotFoundError: a local folder or file is missing (from the loaders).
    """
    from gaffer_diffusion.loading import load_pretrained, load_zero123_xl

    match source.init:
        case "preset":
            cfg = get_preset(source.preset)
            if source.resolution is not None:
                if source.resolution % cfg.vae.downsampling_factor:
                    raise ConfigError(
                        f"`model.resolution` is {source.resolution}; it must be a multiple of "
                        f"{cfg.vae.downsampling_factor}."
                    )
                cfg = cfg.with_resolution(source.resolution)
            return build_model(cfg, seed=source.seed)
        case "zero123-xl":
            result = load_zero123_xl(str(source.path))
            logger.info("%s", result.report.summary())
            return result.model
        case "pretrained":
            result = load_pretrained(str(source.path))
            logger.info("%s", result.report.summary())
            return result.model


def _make_accelerator(config: TrainConfig) -> Any:
    try:
        from accelerate import Accelerator
        from accelerate.state import AcceleratorState
    except ImportError as exc:
        raise MissingDependencyError(
            'Training needs accelerate: pip install "gaffer-diffusion[train]"'
        ) from exc
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    if world_size == 1:
        # a fresh single-process state per call, so one process can run several trainings (tests)
        AcceleratorState._reset_state(reset_partial_state=True)
    mixed_precision = config.train.mixed_precision
    if mixed_precision == "bf16" and not _gpu_available() and not cpu_has_bf16():
        # measured (gaffer-tiny stage 3, 2-core AMD EPYC with AVX2 only): 75 s per step in emulated
        # bf16 vs 2.6 s in fp32 (with AVX512-BF16, bf16 was faster than fp32). On a CPU bf16 is a
        # speed choice only, so fp32 keeps the run's results and makes it feasible (CI's smoke
        # training did 2 steps in 3 minutes on such a machine before this fallback).
        logger.warning(
            "`train.mixed_precision` bf16 on a CPU without native bf16 (no AVX512-BF16/AMX): torch "
            "would emulate it, about 30x slower; training in fp32 instead "
            '(set `train.mixed_precision` to "no" to silence this).'
        )
        mixed_precision = "no"
    # Several processes on a machine without a GPU (`torchrun`, `accelerate launch --multi_gpu`):
    # accelerate makes them one gloo group only when told `cpu`; without it each process found
    # itself alone (DistributedType.NO) and N copies trained into the same output_dir.
    on_cpu = world_size > 1 and not _gpu_available()
    acc = Accelerator(
        mixed_precision=mixed_precision,
        gradient_accumulation_steps=config.train.grad_accum,
        project_dir=str(config.output_dir),
        cpu=on_cpu,
    )
    if acc.num_processes != world_size:
        raise ConfigError(
            f"the launcher started {world_size} processes (WORLD_SIZE) but accelerate joined "
            f"{acc.num_processes}; launch with `accelerate launch --multi_gpu --num_processes N` or "
            "`torchrun --nproc_per_node N` (on a CPU-only machine `accelerate launch --cpu` starts "
            "one process)."
        )
    if config.train.mixed_precision == "fp16" and acc.device.type == "cpu":
        logger.warning(
            "`train.mixed_precision` fp16 on a CPU: autocast/grad scaling are GPU features"
        )
    return acc


def _gpu_available() -> bool:
    """Whether accelerate will place the run on a GPU (CUDA or Apple MPS)."""
    mps = getattr(torch.backends, "mps", None)
    return torch.cuda.is_available() or bool(mps is not None and mps.is_available())


def cpu_has_bf16() -> bool:
    """Whether this CPU runs bf16 natively (oneDNN's check: AVX512-BF16 or AMX)."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def _batches(loader: torch.utils.data.DataLoader) -> Iterator[TrainBatch]:
    yield from loader


@dataclass(frozen=True, kw_only=True)
class _Networks:
    """The model with its frozen parts on the device, the prepared UNet and optimiser, the EMA."""

    model: NeuralGafferModel
    objective: TrainingObjective
    unet: torch.nn.Module
    optimizer: torch.optim.Optimizer
    ema: EMAModel | None


def _networks(cfg: TrainConfig, acc: Any) -> _Networks:
    """Build the model, freeze VAE and CLIP on the device, prepare the UNet and AdamW."""
    model = build_training_model(cfg.model)
    objective = TrainingObjective(cfg, acc, model)
    for frozen in (model.vae, model.image_encoder):
        # VAE and CLIP are frozen (official implementation §3); plain Module.to avoids diffusers' log
        torch.nn.Module.to(frozen.requires_grad_(False).eval(), acc.device, objective.weight_dtype)
    unet = model.unet
    unet.requires_grad_(True).train()
    if cfg.train.gradient_checkpointing:
        unet.enable_gradient_checkpointing()
    o = cfg.optim
    optimizer = torch.optim.AdamW(
        unet.parameters(), lr=o.lr, betas=o.betas, weight_decay=o.weight_decay, eps=o.eps
    )
    unet, optimizer = acc.prepare(unet, optimizer)
    ema = EMAModel(acc.unwrap_model(unet), cfg.train.ema_decay) if cfg.train.ema_decay > 0 else None
    return _Networks(model=model, objective=objective, unet=unet, optimizer=optimizer, ema=ema)


def _datasets(cfg: TrainConfig, res: int) -> tuple[RelightTrainDataset, ValidationSet | None]:
    """The training dataset and the held-out validation set (None when validation is off or no
    object is held out)."""
    # renders and converted authors' splits (`gaffer-data convert-authors`) alike, in any mix
    train_roots = [cfg.data.root, *cfg.data.extra_roots]
    check_lighting_compat(
        [*train_roots, *([] if cfg.data.val_root is None else [cfg.data.val_root])],
        cfg.data.lighting_compat,
    )
    if cfg.data.val_root is not None:
        val_ids, val_roots = None, [cfg.data.val_root]
        held_out: tuple[str, ...] = ()
    else:
        all_ids = dataset_object_ids(cfg.data.root)
        _, val_list = split_object_ids(all_ids, cfg.data.val_objects)
        val_ids, val_roots, held_out = val_list, [cfg.data.root], val_list
    # held-out ids are left out of every training root (a copy of one elsewhere cannot leak in)
    train_ds = RelightTrainDataset(
        train_roots, cfg.data, res, seed=cfg.train.seed, exclude=held_out
    )
    valset: ValidationSet | None = None
    if cfg.validation.every_steps > 0 and (val_ids is None or val_ids):
        val_ds = RelightTrainDataset(
            val_roots,
            dataclasses.replace(cfg.data, targets_per_sample=1),
            res,
            seed=cfg.validation.seed,
            include=val_ids,
        )
        valset = build_validation_set(val_ds, cfg.validation.num_samples)
    logger.info(
        "training on %d views of %d objects; %s held-out validation pairs",
        len(train_ds),
        len(train_ds.objects),
        0 if valset is None else valset.size,
    )
    return train_ds, valset


def _loader(
    train_ds: RelightTrainDataset, cfg: TrainConfig, acc: Any, samples_seen: int
) -> torch.utils.data.DataLoader:
    """This process's data loader, continuing the run's data order after `samples_seen` samples."""
    sampler = KeySampler(
        len(train_ds),
        seed=cfg.train.seed,
        start=samples_seen,
        rank=acc.process_index,
        world_size=acc.num_processes,
    )
    nw = cfg.data.num_workers
    return torch.utils.data.DataLoader(
        train_ds,
        batch_size=cfg.train.batch_size,
        sampler=sampler,
        collate_fn=collate_items,
        num_workers=nw,
        pin_memory=acc.device.type == "cuda",
        persistent_workers=nw > 0,
        prefetch_factor=4 if nw > 0 else None,
    )


def _stop_requested(
    cfg: TrainConfig, acc: Any, sigterm: SigtermFlag, t_start: float
) -> StopReason | None:
    """ "sigterm" when any process got SIGTERM, "time_limit" past `train.max_time_s`, else None."""
    flag = torch.tensor([1.0 if sigterm.set else 0.0], device=acc.device)
    if float(acc.reduce(flag, reduction="sum").item()) > 0:
        return "sigterm"
    limit = cfg.train.max_time_s
    if limit is not None and time.perf_counter() - t_start > limit:
        return "time_limit"
    return None


def _save_final_model(
    cfg: TrainConfig, acc: Any, model: NeuralGafferModel, unet_module: Any, ema: EMAModel | None
) -> Path | None:
    """`output_dir/final`: the EMA model in our format (main process; None on the others)."""
    final_model: Path | None = None
    if acc.is_main_process:
        from gaffer_diffusion.loading import save_pretrained
        from gaffer_diffusion.suggested import suggestion_from_training_config

        final_model = save_pretrained(
            sampling_model(model, unet_module, ema),
            Path(cfg.output_dir) / "final",
            suggested=suggestion_from_training_config(cfg.to_dict()),
        )
    acc.wait_for_everyone()
    return final_model


def train(
    config: TrainConfig,
    *,
    resume: bool | str | Path = False,
    on_step: StepCallback | None = None,
) -> TrainResult:
    """Train (or resume training) the UNet as `config` says.

    Args:
        config: the run.
        resume: False (start fresh; refuses a non-empty checkpoint folder), True (the newest complete
            checkpoint under `output_dir/checkpoints`) or a checkpoint folder.
        on_step: called as `on_step(step, loss)` after every optimiser step (tests, notebooks).

    Returns:
        A `TrainResult`.

    Raises:
        ResumeError: `resume` without a checkpoint, or fresh start over existing checkpoints.
        TrainingDivergedError: too many consecutive NaN/Inf steps (a checkpoint is written first).
        DataError: no usable data.
    """
    t_start = time.perf_counter()
    cfg = config
    acc = _make_accelerator(cfg)
    out = Path(cfg.output_dir)
    ckpt_root = out / "checkpoints"
    prepare_checkpoint_root(acc, ckpt_root)
    resume_from = resume_point(resume, ckpt_root)
    if cfg.train.allow_tf32 and torch.cuda.is_available():
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True

    nets = _networks(cfg, acc)
    model, unet, ema = nets.model, nets.unet, nets.ema
    train_ds, valset = _datasets(cfg, model.config.resolution)

    state = ckpt.TrainState(
        step=0, samples_seen=0, world_size=acc.num_processes, config=cfg.to_dict()
    )
    if resume_from is not None:
        state, ema = restore_checkpoint(
            resume_from,
            acc,
            unet,
            ema,
            cfg.train.ema_decay,
            per_step_samples=cfg.train.batch_size * cfg.train.grad_accum * acc.num_processes,
        )
        # the next checkpoints describe this run (its process count and config), not the resumed
        # one's: a 1 -> 2 process resume wrote world_size 1 before
        state = dataclasses.replace(state, world_size=acc.num_processes, config=cfg.to_dict())
    start_step = state.step

    batches = _batches(_loader(train_ds, cfg, acc, state.samples_seen))
    log = MetricsLogger(
        out / "logs", enabled=acc.is_main_process, tensorboard=cfg.logging.tensorboard
    )
    progress = open_progress(cfg, acc.is_main_process, state.step)
    unet_module = acc.unwrap_model(unet)
    parts = StepParts(
        cfg=cfg,
        acc=acc,
        unet=unet,
        unet_module=unet_module,
        optimizer=nets.optimizer,
        ema=ema,
        objective=nets.objective,
        per_step_samples=cfg.train.batch_size * cfg.train.grad_accum * acc.num_processes,
    )
    validation = TrainingValidation(
        cfg=cfg,
        valset=valset,
        model=model,
        unet_module=unet_module,
        weight_dtype=nets.objective.weight_dtype,
        device=acc.device,
        is_main_process=acc.is_main_process,
        out=out,
        log=log,
    )

    losses: list[float] = []
    validations: list[ValidationResult] = []
    last_ckpt: Path | None = resume_from
    window = LogWindow()
    stop: StopReason = "max_steps"

    def save(step_state: ckpt.TrainState) -> Path:
        return save_checkpoint(acc, ckpt_root, step_state, ema, cfg.checkpoint.keep)

    def run_validation(step: int) -> None:
        result = validation.run(step, ema)
        if result is not None:
            validations.append(result)

    with SigtermFlag(cfg.checkpoint.on_sigterm) as sigterm:
        try:
            while state.step < cfg.train.max_steps:
                outcome = optimizer_step(parts, state, batches)
                state = outcome.state
                losses.append(outcome.loss if outcome.applied else float("nan"))
                window.add(outcome, parts.per_step_samples)
                show_progress(progress, outcome)
                if on_step is not None:
                    on_step(state.step, outcome.loss)

                if state.consecutive_nonfinite >= cfg.train.max_consecutive_nonfinite:
                    # the weights were never touched by the bad steps: this checkpoint is usable
                    last_ckpt = save(state)
                    raise TrainingDivergedError(
                        state.step,
                        state.consecutive_nonfinite,
                        last_ckpt,
                        cfg.train.mixed_precision,
                    )
                if log_due(cfg, state.step):
                    window = log_window(log, window, outcome)
                ve = cfg.validation.every_steps
                if ve > 0 and state.step % ve == 0 and state.step < cfg.train.max_steps:
                    run_validation(state.step)
                if (
                    state.step % cfg.checkpoint.every_steps == 0
                    and state.step < cfg.train.max_steps
                ):
                    last_ckpt = save(state)
                requested = _stop_requested(cfg, acc, sigterm, t_start)
                if requested is not None:
                    stop = requested
                    break
        finally:
            if progress is not None:
                progress.close()

    if last_ckpt is None or ckpt.read_state(last_ckpt).step != state.step:
        last_ckpt = save(state)
    final_model: Path | None = None
    if stop != "sigterm":
        if cfg.validation.every_steps > 0:
            run_validation(state.step)
        final_model = _save_final_model(cfg, acc, model, unet_module, ema)
    log.close()
    if state.skipped_samples:
        logger.warning("%d unreadable samples were skipped in this run", state.skipped_samples)
    end_training_errors = _end_training(acc)
    return TrainResult(
        step=state.step,
        start_step=start_step,
        losses=tuple(losses),
        stop_reason=stop,
        checkpoint=last_ckpt,
        final_model=final_model,
        skipped_steps=state.skipped_steps,
        skipped_samples=state.skipped_samples,
        validations=tuple(validations),
        seconds=time.perf_counter() - t_start,
        end_training_errors=end_training_errors,
    )


def _end_training(acc: Any) -> int:
    """`acc.end_training()` (the trackers' last flush, the process group's teardown): 1 if it failed.

    It runs after the checkpoint and the final model are on disk, so a teardown failure (torch.distributed
    raises RuntimeError, a tracker's flush OSError) is logged and counted in
    `TrainResult.end_training_errors` rather than thrown away with a finished run. Anything else is a
    bug and propagates.
    """
    try:
        acc.end_training()
    except (RuntimeError, OSError) as exc:
        logger.warning(
            "accelerate's end_training() failed after the results were saved (%s: %s); counted in "
            "`TrainResult.end_training_errors`.",
            type(exc).__name__,
            exc,
        )
        return 1
    return 0


def load_checkpoint_model(checkpoint: str | Path, *, use_ema: bool = True) -> NeuralGafferModel:
    """Rebuild the model of a training checkpoint (its config's networks + the saved UNet / EMA).

    Args:
        checkpoint: a `checkpoint-*` folder.
        use_ema: load the EMA weights (else the raw trained weights).

    Raises:
        ResumeError: not a complete checkpoint.
    """
    from gaffer_diffusion.loading import load_checked, read_state_dict

    folder = Path(checkpoint)
    state = ckpt.read_state(folder)
    cfg = TrainConfig.from_dict(state.config)
    model = build_training_model(cfg.model)
    weights = folder / "model.safetensors"
    if not weights.is_file():
        weights = folder / "pytorch_model.bin"
    load_checked(model.unet, read_state_dict(weights), source=str(weights))
    if use_ema and (folder / ckpt.EMA_NAME).is_file():
        ema = EMAModel(model.unet, cfg.train.ema_decay or 0.9999)
        ema.load(str(folder / ckpt.EMA_NAME))
        ema.copy_to(model.unet)
    return model.eval()
