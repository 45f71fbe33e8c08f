"""Typed, frozen training configuration, loaded from JSON (official implementation §3).

A config file is one JSON object with the sections below; every key is optional except `data.root` and
`output_dir`, and unknown keys are an error (a typo must not silently train with a default). Relative
paths are resolved against the config file's folder.

```json
{
  "output_dir": "runs/neural-gaffer",
  "model": {"init": "zero123-xl", "path": "zero123-xl-diffusers"},
  "data": {"root": "renders/objaverse", "val_objects": 48},
  "optim": {"lr": 1e-4, "warmup_steps": 100},
  "train": {"max_steps": 80000, "batch_size": 64, "mixed_precision": "fp16"},
  "checkpoint": {"every_steps": 1000, "keep": 3},
  "logging": {"every_steps": 10},
  "validation": {"every_steps": 2000, "num_samples": 16}
}
```

The defaults are the paper's recipe (official implementation §3): AdamW (lr 1e-4, betas (0.9, 0.999),
weight decay 1e-2, eps 1e-8), 100 warm-up steps then constant, epsilon-MSE on uniform timesteps, CFG
dropout p = 0.05, two target lightings per sample, 10% area-light inputs, no gradient clipping.
"""

import dataclasses
import json
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from gaffer_diffusion.configs import PRESETS, PresetName
from gaffer_diffusion.errors import ConfigError
from gaffer_envmap.compat_mode import Compat, compat_problem

ModelInit = Literal["preset", "zero123-xl", "pretrained"]
"""Where the networks come from: a random-init preset (tiny tests), a local Zero-1-to-3 XL folder (with
the 8 -> 16 `conv_in` surgery; the paper's initialisation) or a model folder in our format."""

MixedPrecision = Literal["no", "fp16", "bf16"]
"""accelerate's mixed-precision modes (fp32 master weights of the UNet in every mode)."""

LightingCompat = Compat
"""gaffer-envmap's encoding: "default" for new training, "neural-gaffer" to fine-tune the release."""

LatentMode = Literal["mode", "sample"]

LossSpace = Literal["diffusion", "display_object"]
"""What the loss compares (`TrainLoopConfig.loss_space`)."""


@dataclass(frozen=True, kw_only=True)
class ModelSource:
    """Which networks to train.

    Attributes:
        init: "preset" (random init of `preset`), "zero123-xl" (`path` = a local Zero-1-to-3 XL diffusers
            folder; conv_in widened 8 -> 16) or "pretrained" (`path` = a `save_pretrained` folder).
        preset: preset name for `init="preset"`.
        path: folder for the other two inits.
        resolution: override the image size of a preset (must be a multiple of 8); None keeps it.
        seed: seed of the random initialisation.
    """

    init: ModelInit = "preset"
    preset: PresetName = "tiny"
    path: Path | None = None
    resolution: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.init not in ("preset", "zero123-xl", "pretrained"):
            raise ConfigError(
                f"`model.init` is {self.init!r}; expected 'preset', 'zero123-xl' or 'pretrained'."
            )
        if self.init == "preset" and self.preset not in PRESETS:
            raise ConfigError(
                f"`model.preset` is {self.preset!r}; expected one of {list(PRESETS)}."
            )
        if self.init != "preset" and self.path is None:
            raise ConfigError(
                f"`model.init` is {self.init!r}, which needs `model.path` (a local folder); nothing is "
                "downloaded at run time."
            )


@dataclass(frozen=True, kw_only=True)
class DataConfig:
    """The rendered dataset(s) and how samples are drawn from them.

    Attributes:
        root: a `gaffer-data render` output folder, or a split of the authors' release converted by
            `gaffer-data convert-authors` (its pre-encoded lighting maps are used as they are).
        extra_roots: more training folders of either kind, sampled together with `root` (one item per
            object view over all of them). Renders mixed with authors' splits (here or in `val_root`)
            need `lighting_compat="neural-gaffer"`, the authors' encoding.
        val_root: a separate held-out folder (either kind); None holds out `val_objects` objects of
            `root` (and leaves objects with the same ids out of `extra_roots`).
        val_objects: objects of `root` held out for validation when `val_root` is None.
        envmap_dirs: folders searched (by file name) for environment maps whose recorded source path no
            longer exists (datasets moved between machines).
        targets_per_sample: target lightings per sample, same view and input (paper: 2).
        area_light_prob: probability that the input is the area-light render (paper: 0.1).
        mirror_prob: probability that a view (input and its targets) is flipped left-right, with
            its camera-frame lighting maps mirrored to match (`gaffer_envmap.augment.mirror_camera_x`).
            Relighting commutes with that mirror, so this doubles the views at no render cost; the
            paper does not do it (0.0, the default).
        object_fraction: None (the paper): each render is used whole. A fraction f: every view
            (its input and targets alike) is cropped to the square centred on its object in which
            the object's longer side spans f of the side (`gaffer_diffusion.preprocess.
            object_square`, the framing `prepare_object_image` gives photos), so a small model's
            pixels go to the object. The view's camera frame is kept (the crop is small next to the
            lighting's angular detail).
        target_exposure_stops: each target's environment map and render are re-exposed together by
            a gain of 2^s, s uniform in [-this, this] stops (`gaffer_diffusion.training.exposure`:
            exact for Standard-view-transform renders, up to 8-bit rounding), so the output's level
            follows the target map's. 0 (the default, the paper): off.
        target_tint_stops: the same, per channel: channel c of each target's map and render is scaled
            by 2^t_c more, t_c uniform in [-this, this] stops, so the output's colour follows the
            target map's colour cast. 0 (the default, the paper): off.
        envmap_height: environment maps are resized (solid-angle exact) to `[h, 2h]` so a batch stacks;
            the rotation to the camera frame happens later, batched on the training device.
        lighting_compat: gaffer-envmap encoding of the lighting maps.
        max_radiance: radiance is clamped to this value (and NaN/Inf sanitised) when an environment map
            is read; an extreme map cannot overflow the float32 HDR normaliser.
        envmap_cache_size: decoded environment maps kept per data-loader worker.
        num_workers: DataLoader worker processes (0: load in the training process).
        max_load_retries: an item whose files are missing or corrupt is replaced by another one this many
            times before the data loader gives up with an error.
    """

    root: Path
    extra_roots: tuple[Path, ...] = ()
    val_root: Path | None = None
    val_objects: int = 1
    envmap_dirs: tuple[Path, ...] = ()
    targets_per_sample: int = 2
    area_light_prob: float = 0.1
    mirror_prob: float = 0.0
    object_fraction: float | None = None
    target_exposure_stops: float = 0.0
    target_tint_stops: float = 0.0
    envmap_height: int = 128
    lighting_compat: LightingCompat = "default"
    max_radiance: float = 1e30
    envmap_cache_size: int = 64
    num_workers: int = 0
    max_load_retries: int = 16

    def __post_init__(self) -> None:
        if self.targets_per_sample < 1:
            raise ConfigError(f"`data.targets_per_sample` is {self.targets_per_sample}; need >= 1.")
        if not 0.0 <= self.area_light_prob <= 1.0:
            raise ConfigError(f"`data.area_light_prob` is {self.area_light_prob}; need [0, 1].")
        if self.object_fraction is not None and not 0.0 < self.object_fraction <= 1.0:
            raise ConfigError(
                f"`data.object_fraction` is {self.object_fraction}; expected a fraction in (0, 1] "
                "(0.8: the object's longer side spans 80% of the crop), or null for the full render."
            )
        if not 0.0 <= self.mirror_prob <= 1.0:
            raise ConfigError(f"`data.mirror_prob` is {self.mirror_prob}; need [0, 1].")
        for key in ("target_exposure_stops", "target_tint_stops"):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0.0 <= value <= 4.0):
                raise ConfigError(
                    f"`data.{key}` is {value}; expected stops in [0, 4] (0 turns it off)."
                )
        if self.envmap_height < 2:
            raise ConfigError(f"`data.envmap_height` is {self.envmap_height}; need >= 2.")
        if not (math.isfinite(self.max_radiance) and self.max_radiance > 0):
            raise ConfigError(f"`data.max_radiance` is {self.max_radiance}; need finite > 0.")
        if (problem := compat_problem("data.lighting_compat", self.lighting_compat)) is not None:
            raise ConfigError(problem)
        if self.val_objects < 0 or self.num_workers < 0 or self.max_load_retries < 0:
            raise ConfigError(
                "`data.val_objects`, `data.num_workers` and `data.max_load_retries` must be >= 0."
            )


@dataclass(frozen=True, kw_only=True)
class OptimConfig:
    """AdamW and the learning-rate schedule (paper: constant after a linear warm-up).

    Attributes:
        lr: peak learning rate (1e-4).
        betas: AdamW betas ((0.9, 0.999)).
        weight_decay: 1e-2.
        eps: 1e-8.
        warmup_steps: linear warm-up from lr / warmup_steps to lr (100).
        max_grad_norm: clip the global gradient norm to this; None disables clipping (the paper).
    """

    lr: float = 1e-4
    betas: tuple[float, float] = (0.9, 0.999)
    weight_decay: float = 1e-2
    eps: float = 1e-8
    warmup_steps: int = 100
    max_grad_norm: float | None = None

    def __post_init__(self) -> None:
        if not self.lr > 0 or self.warmup_steps < 0 or len(self.betas) != 2:
            raise ConfigError(
                f"`optim.lr` ({self.lr}) must be > 0, `optim.warmup_steps` ({self.warmup_steps}) >= 0 "
                f"and `optim.betas` ({self.betas}) a pair."
            )
        if self.max_grad_norm is not None and not self.max_grad_norm > 0:
            raise ConfigError(f"`optim.max_grad_norm` is {self.max_grad_norm}; need > 0 or null.")

    def lr_at(self, step: int) -> float:
        """Learning rate of optimiser step `step` (0-based): linear warm-up, then constant."""
        if self.warmup_steps <= 0:
            return self.lr
        return self.lr * min(1.0, (step + 1) / self.warmup_steps)


@dataclass(frozen=True, kw_only=True)
class TrainLoopConfig:
    """Steps, batch, precision and the diffusion objective.

    Attributes:
        max_steps: optimiser steps (paper: 80K).
        max_time_s: stop (with a checkpoint) after this many seconds of training; None: no limit.
        batch_size: samples per device per micro-step; each sample has `data.targets_per_sample`
            targets, so the UNet sees `batch_size * targets_per_sample` items (paper: 64 x 2).
        grad_accum: micro-steps per optimiser step.
        seed: seed of the data order, noise, timesteps and dropout (resume-exact).
        mixed_precision: "no", "fp16" or "bf16" (paper: fp16).
        gradient_checkpointing: recompute UNet activations in the backward pass (paper: yes).
        cfg_dropout_p: p of the CFG dropout (paper: 0.05; one uniform r per UNet item: r < 2p drops the
            CLIP embedding, p <= r < 3p drops the three conditioning latents).
        cond_latent_mode: conditioning latents from the VAE posterior "mode" (ours) or a "sample".
        ema_decay: EMA decay of the UNet weights (warm-up min(decay, (1 + n) / (10 + n))); 0 disables.
        max_consecutive_nonfinite: stop with `TrainingDivergedError` (and a checkpoint of the last good
            weights) after this many consecutive skipped steps with NaN/Inf loss or gradients.
        allow_tf32: allow TF32 matmuls on Ampere+ GPUs.
        timestep_range: training timesteps t ~ U{lo..hi} (paper: the whole schedule, [0, 999]). A
            late range such as [900, 999] spends the training on the noisiest steps, the only ones a
            one-step sampler from t = 999 uses (diffusers' training scripts call this a timestep
            bias); the model then samples well in one or few steps and worse in many.
        residual_loss_floor: None (the paper): plain MSE over the batch. A value c (residual models
            only) weights each item's MSE by 1 / (mean(z0^2) + c), normalised to mean 1 over the
            batch, where z0 is its scaled target - input: each pair counts by its error relative
            to how much the lighting changes it, as mean per-image PSNR does. Plain MSE lets the
            pairs with the largest change (e.g. night -> studio) dominate, and the model then
            invents changes on pairs whose lighting barely differs.
        loss_space: "diffusion" (the paper): MSE of the UNet output against the scheduler's
            prediction target in latent space. "display_object" (pixel-space residual models):
            the clean sample the UNet's output implies at its timestep, decoded and applied to the
            input, against the target image in display space over the object's alpha: minus the
            mean of the pairs' masked PSNR, raw and channel-aligned (`display_object_loss`), the
            scores the model is judged on. With `timestep_range` [999, 999] this
            trains the one-step sampler end to end, as Garcia et al. 2024 ("Fine-Tuning
            Image-Conditional Diffusion Models is Easier than You Think") fine-tune Marigold with
            its task loss at a single step; it needs the zero-terminal-SNR schedule's
            v-prediction or sample prediction (epsilon cannot give the sample at t = 999).
    """

    max_steps: int = 80_000
    max_time_s: float | None = None
    batch_size: int = 64
    grad_accum: int = 1
    seed: int = 0
    mixed_precision: MixedPrecision = "fp16"
    gradient_checkpointing: bool = True
    cfg_dropout_p: float = 0.05
    cond_latent_mode: LatentMode = "mode"
    ema_decay: float = 0.9999
    max_consecutive_nonfinite: int = 20
    allow_tf32: bool = True
    timestep_range: tuple[int, int] = (0, 999)
    residual_loss_floor: float | None = None
    loss_space: LossSpace = "diffusion"

    def __post_init__(self) -> None:
        if self.loss_space not in ("diffusion", "display_object"):
            raise ConfigError(
                f"`train.loss_space` is {self.loss_space!r}; expected 'diffusion' or "
                "'display_object'."
            )
        if self.loss_space == "display_object" and self.residual_loss_floor is not None:
            raise ConfigError(
                "`train.residual_loss_floor` weighs the latent-space loss; with `train.loss_space` "
                "'display_object' set it to null."
            )
        if self.residual_loss_floor is not None and not self.residual_loss_floor > 0:
            raise ConfigError(
                f"`train.residual_loss_floor` is {self.residual_loss_floor}; expected a positive "
                "number (e.g. 0.1) or null for the paper's plain MSE."
            )
        lo, hi = self.timestep_range
        if not 0 <= lo <= hi:
            raise ConfigError(
                f"`train.timestep_range` is {list(self.timestep_range)}; expected [lo, hi] with "
                "0 <= lo <= hi < the schedule's num_train_timesteps (1000)."
            )
        if self.max_steps < 1 or self.batch_size < 1 or self.grad_accum < 1:
            raise ConfigError(
                f"`train.max_steps` ({self.max_steps}), `train.batch_size` ({self.batch_size}) and "
                f"`train.grad_accum` ({self.grad_accum}) must be >= 1."
            )
        if self.mixed_precision not in ("no", "fp16", "bf16"):
            raise ConfigError(
                f"`train.mixed_precision` is {self.mixed_precision!r}; expected 'no', 'fp16', 'bf16'."
            )
        if not 0.0 <= self.cfg_dropout_p <= 1.0 / 3.0:
            raise ConfigError(f"`train.cfg_dropout_p` is {self.cfg_dropout_p}; need [0, 1/3].")
        if self.cond_latent_mode not in ("mode", "sample"):
            raise ConfigError(
                f"`train.cond_latent_mode` is {self.cond_latent_mode!r}; expected 'mode' or 'sample'."
            )
        if not 0.0 <= self.ema_decay < 1.0:
            raise ConfigError(f"`train.ema_decay` is {self.ema_decay}; need [0, 1).")
        if self.max_consecutive_nonfinite < 1:
            raise ConfigError("`train.max_consecutive_nonfinite` must be >= 1.")


@dataclass(frozen=True, kw_only=True)
class CheckpointConfig:
    """Periodic checkpoints (written to a temporary folder, then renamed: a kill never corrupts one).

    Attributes:
        every_steps: save every this many optimiser steps (and at the end).
        keep: newest checkpoints kept; older ones are deleted after a new one is complete.
        on_sigterm: save a checkpoint and stop cleanly on SIGTERM (cluster pre-emption).
    """

    every_steps: int = 1000
    keep: int = 3
    on_sigterm: bool = True

    def __post_init__(self) -> None:
        if self.every_steps < 1 or self.keep < 1:
            raise ConfigError(
                f"`checkpoint.every_steps` ({self.every_steps}) and `checkpoint.keep` ({self.keep}) "
                "must be >= 1."
            )


@dataclass(frozen=True, kw_only=True)
class LoggingConfig:
    """Scalars to TensorBoard (when installed) and always to `logs/train.jsonl`.

    Attributes:
        every_steps: log every this many optimiser steps.
        tensorboard: also write TensorBoard events when `tensorboard` is importable.
        progress_bar: show a tqdm bar on the main process.
    """

    every_steps: int = 10
    tensorboard: bool = True
    progress_bar: bool = True

    def __post_init__(self) -> None:
        if self.every_steps < 1:
            raise ConfigError(f"`logging.every_steps` is {self.every_steps}; need >= 1.")


@dataclass(frozen=True, kw_only=True)
class ValidationConfig:
    """Relight held-out samples with `RelightPipeline` and score PSNR against the ground truth.

    Attributes:
        every_steps: validate every this many steps (and at the end); 0 disables validation.
        num_samples: held-out (input, target) pairs, fixed for the whole run.
        num_inference_steps: DDIM steps (paper: 50).
        guidance_scale: CFG scale (paper: 3).
        use_ema: sample with the EMA weights (as the authors validate).
        batch_size: samples per pipeline call.
        save_images: write an input | prediction | ground truth sheet per validation.
        seed: seed of the held-out pairs and the sampling noise.
    """

    every_steps: int = 2000
    num_samples: int = 8
    num_inference_steps: int = 50
    guidance_scale: float = 3.0
    use_ema: bool = True
    batch_size: int = 8
    save_images: bool = True
    seed: int = 1234

    def __post_init__(self) -> None:
        if self.every_steps < 0 or self.num_samples < 1 or self.batch_size < 1:
            raise ConfigError(
                "`validation.every_steps` must be >= 0, `validation.num_samples` and "
                "`validation.batch_size` >= 1."
            )


@dataclass(frozen=True, kw_only=True)
class TrainConfig:
    """A complete training run.

    Attributes:
        output_dir: checkpoints (`checkpoints/`), logs (`logs/`), validation sheets (`val/`) and the
            final EMA model (`final/`, our model format).
        model: where the networks come from.
        data: datasets and sampling.
        optim: optimiser and schedule.
        train: loop, batch, precision, objective.
        checkpoint: checkpoint cadence and rotation.
        logging: scalar logging.
        validation: held-out relighting.

    Example:
        >>> cfg = TrainConfig.from_dict({"output_dir": "run", "data": {"root": "renders"}})
        >>> cfg.optim.lr, cfg.train.batch_size, cfg.data.targets_per_sample
        (0.0001, 64, 2)
    """

    output_dir: Path
    model: ModelSource = field(default_factory=ModelSource)
    data: DataConfig
    optim: OptimConfig = field(default_factory=OptimConfig)
    train: TrainLoopConfig = field(default_factory=TrainLoopConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    validation: ValidationConfig = field(default_factory=ValidationConfig)

    @classmethod
    def from_dict(cls, data: dict[str, Any], *, base_dir: Path | None = None) -> "TrainConfig":
        """Build a config from a JSON-like dict.

        Args:
            data: the parsed JSON object.
            base_dir: relative paths are resolved against it (None: kept as given).

        Raises:
            ConfigError: unknown keys, wrong types or out-of-range values, naming the key.
        """
        return _build(cls, data, "", base_dir)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (paths as strings) that `from_dict` reads back."""
        return json.loads(json.dumps(dataclasses.asdict(self), default=str))

    def replace(self, **sections: Any) -> "TrainConfig":
        """A copy with whole sections or fields replaced (`cfg.replace(output_dir=...)`)."""
        return dataclasses.replace(self, **sections)


def load_config(path: str | Path) -> TrainConfig:
    """Read a `TrainConfig` from a JSON file; relative paths resolve against the file's folder.

    Raises:
        ConfigError: the file is missing, is not JSON, or holds an invalid config.
    """
    p = Path(path).expanduser()
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(
            f"`--config` {p} does not exist; see packages/gaffer-diffusion/configs/ for examples."
        ) from exc
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"`--config` {p} is not readable JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"`--config` {p} must hold a JSON object, not {type(data).__name__}.")
    data.pop("$comment", None)
    return TrainConfig.from_dict(data, base_dir=p.resolve().parent)


def _build(cls: type, data: Any, where: str, base_dir: Path | None) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"`{where or 'config'}` must be a JSON object, got {data!r}.")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names - {"$comment"})
    if unknown:
        raise ConfigError(
            f"Unknown key(s) {unknown} in `{where or 'config'}`; valid keys: {sorted(names)}."
        )
    kwargs = {
        k: _convert(hints[k], v, f"{where}.{k}" if where else k, base_dir)
        for k, v in data.items()
        if k != "$comment"
    }
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"`{where or 'config'}` is incomplete: {exc}.") from exc


def _convert(tp: Any, value: Any, where: str, base_dir: Path | None) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(inner[0], value, where, base_dir)
    if dataclasses.is_dataclass(tp):
        return _build(tp, value, where, base_dir)  # type: ignore[arg-type]
    if tp is Path:
        if not isinstance(value, str):
            raise ConfigError(f"`{where}` must be a path string, got {value!r}.")
        p = Path(value).expanduser()
        return p if p.is_absolute() or base_dir is None else (base_dir / p)
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"`{where}` must be a list, got {value!r}.")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(
                _convert(args[0], v, f"{where}[{i}]", base_dir) for i, v in enumerate(value)
            )
        if len(value) != len(args):
            raise ConfigError(f"`{where}` must have {len(args)} entries, got {value!r}.")
        return tuple(
            _convert(a, v, f"{where}[{i}]", base_dir) for i, (a, v) in enumerate(zip(args, value))
        )
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"`{where}` is {value!r}; expected one of {list(args)}.")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"`{where}` must be true or false, got {value!r}.")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"`{where}` must be an integer, got {value!r}.")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"`{where}` must be a number, got {value!r}.")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"`{where}` must be a string, got {value!r}.")
        return value
    return value
