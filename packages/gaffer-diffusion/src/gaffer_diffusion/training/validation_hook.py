"""Validation inside `train`: which weights are sampled, how the result is logged."""

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.tracking import MetricsLogger
from gaffer_diffusion.training.validation import (
    ValidationResult,
    ValidationSet,
    sampling_model,
    validate,
)

logger = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class TrainingValidation:
    """What a validation during training needs (the EMA is passed per call: a resume may replace it)."""

    cfg: TrainConfig
    valset: ValidationSet | None
    model: NeuralGafferModel
    unet_module: torch.nn.Module
    weight_dtype: torch.dtype
    device: Any
    is_main_process: bool
    out: Path
    log: MetricsLogger

    def run(self, step: int, ema: EMAModel | None) -> ValidationResult | None:
        """Validate at `step` on the main process (EMA weights when `validation.use_ema`), log the
        PSNRs (and the sheet to TensorBoard); None when there is no validation set or on another
        process."""
        if self.valset is None or not self.is_main_process:
            return None
        cfg = self.cfg
        smodel = sampling_model(
            self.model,
            self.unet_module,  # type: ignore[arg-type]
            ema if cfg.validation.use_ema else None,
        )
        dtype = {torch.float16: "float16", torch.bfloat16: "bfloat16"}.get(
            self.weight_dtype, "float32"
        )
        result = validate(
            smodel,
            self.valset,
            cfg.validation,
            step=step,
            compat=cfg.data.lighting_compat,
            device=self.device,
            dtype=dtype,
            sheet_dir=(self.out / "val") if cfg.validation.save_images else None,
        )
        self.log.log(
            step, {"psnr": result.psnr, "psnr_identity": result.psnr_identity}, kind="validation"
        )
        if result.sheet is not None and self.log.tensorboard_enabled:
            from PIL import Image

            self.log.log_image(
                step, "validation/input_pred_gt", np.asarray(Image.open(result.sheet))
            )
        logger.info(
            "step %d validation: PSNR %.2f dB (identity baseline %.2f dB)",
            step,
            result.psnr,
            result.psnr_identity,
        )
        return result
