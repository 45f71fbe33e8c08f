"""Errors raised by `gaffer_diffusion.training` (subclasses of gaffer-diffusion's base error)."""

from gaffer_diffusion.errors import GafferDiffusionError


class DataError(GafferDiffusionError, RuntimeError):
    """The training data cannot be used (empty dataset, or too many unreadable files in a row)."""


class TrainingDivergedError(GafferDiffusionError, FloatingPointError):
    """Too many consecutive steps had NaN/Inf loss or gradients; a checkpoint of the last good weights
    was written first. Carries `step` and `checkpoint` (its folder, or None)."""

    def __init__(
        self, step: int, consecutive: int, checkpoint: object, mixed_precision: str
    ) -> None:
        self.step = step
        self.consecutive = consecutive
        self.checkpoint = checkpoint
        hint = (
            ' fp16 overflows easily: set `train.mixed_precision` to "bf16" (fp32\'s exponent range) or '
            '"no".'
            if mixed_precision == "fp16"
            else ""
        )
        super().__init__(
            f"Training stopped at step {step}: {consecutive} consecutive steps had NaN/Inf loss or "
            f"gradients (skipped, weights untouched). The last good weights are in checkpoint "
            f"{checkpoint}; resume from it with `--resume` after lowering `optim.lr`, enabling "
            f"`optim.max_grad_norm`, or checking the data.{hint}"
        )


class ResumeError(GafferDiffusionError, FileNotFoundError):
    """`--resume` was asked for but no complete checkpoint exists, or it does not fit the config."""
