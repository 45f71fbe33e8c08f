"""Validation: relight held-out samples with `RelightPipeline`, score PSNR against the ground truth.

Every validation uses the same held-out (input, target lighting) pairs and the same sampling seeds, so
the numbers are comparable across steps. The identity baseline (the unrelit input scored against the
target) is reported beside the model's PSNR: a relighting model must beat it.

`TrainingValidation` is validation inside `train`: which weights are sampled (the EMA's when
`validation.use_ema`), on which process, and how the result is logged.
"""

import copy
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diffusers.models.unets.unet_2d_condition import UNet2DConditionModel
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.conditioning import LightingMaps
from gaffer_diffusion.images import quantize_8bit, to_uint8
from gaffer_diffusion.metrics import psnr
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.pipelines import (
    RelightPipeline,
    RuntimeConfig,
    SamplingConfig,
    relight_in_batches,
)
from gaffer_diffusion.training.config import LightingCompat, TrainConfig, ValidationConfig
from gaffer_diffusion.training.dataset import RelightTrainDataset
from gaffer_diffusion.training.ema import EMAModel
from gaffer_diffusion.training.lighting import batch_lighting
from gaffer_diffusion.training.tracking import MetricsLogger
from gaffer_envmap.writers import write_png

logger = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class ValidationSet:
    """Fixed held-out pairs (one target lighting each).

    Pairs of a render carry an environment map, pairs of a converted authors' split their pre-encoded
    maps (`lighting_encoded` True); `envmaps` and `encoded_*` hold only the rows of their kind, in order
    (see `gaffer_diffusion.training.lighting.batch_lighting`).

    Attributes:
        input_images: `[N, 3, H, W]` inputs in [0, 1].
        target_images: `[N, 3, H, W]` ground-truth renders under the target lighting.
        envmaps: `[Ne, He, We, 3]` target environment maps of the Ne render pairs.
        w2c_blender: `[N, 3, 4]` view poses.
        names: `object/view` labels.
        lighting_encoded: `[N]` bool, or None when every pair has an environment map.
        encoded_ldr: `[Na, 3, H, W]` the authors' LDR maps of the other pairs, or None.
        encoded_hdr: `[Na, 3, H, W]` their HDR maps, or None.
        input_masks: `[N, 1, H, W]` the inputs' alphas (the background is kept outside them), or
            None when some item has none (the model's full frame is scored).
    """

    input_images: Float[Tensor, "N 3 H W"]
    target_images: Float[Tensor, "N 3 H W"]
    envmaps: Float[Tensor, "Ne He We 3"]
    w2c_blender: Float[Tensor, "N 3 4"]
    names: tuple[str, ...]
    lighting_encoded: Tensor | None = None
    encoded_ldr: Float[Tensor, "Na 3 H W"] | None = None
    encoded_hdr: Float[Tensor, "Na 3 H W"] | None = None
    input_masks: Float[Tensor, "N 1 H W"] | None = None

    @property
    def size(self) -> int:
        """N."""
        return int(self.input_images.shape[0])


@dataclass(frozen=True, kw_only=True)
class ValidationResult:
    """Scores of one validation.

    Attributes:
        step: training step.
        psnr: mean PSNR (dB) of the relit images against the ground truth.
        psnr_identity: mean PSNR of the unrelit inputs against the ground truth (the baseline).
        psnr_per_item: per-pair PSNR of the relit images.
        psnr_identity_per_item: per-pair PSNR of the baseline.
        sheet: the saved input | prediction | ground-truth image, or None.
    """

    step: int
    psnr: float
    psnr_identity: float
    psnr_per_item: tuple[float, ...]
    psnr_identity_per_item: tuple[float, ...]
    sheet: Path | None = None


def build_validation_set(dataset: RelightTrainDataset, num_samples: int) -> ValidationSet:
    """`num_samples` items of `dataset` (keys 0..N-1, first target of each), loaded once."""
    items = [dataset[k] for k in range(num_samples)]
    env = [i.envmaps[0] for i in items if i.envmaps is not None]
    ldr = [i.encoded_ldr[0] for i in items if i.encoded_ldr is not None]
    hdr = [i.encoded_hdr[0] for i in items if i.encoded_hdr is not None]
    return ValidationSet(
        input_images=torch.stack([i.input_image for i in items]),
        target_images=torch.stack([i.target_images[0] for i in items]),
        envmaps=torch.stack(env) if env else torch.zeros(0, 0, 0, 3),
        w2c_blender=torch.stack([i.w2c_blender for i in items]),
        names=tuple(f"{i.object_id}/{i.view_index}" for i in items),
        lighting_encoded=torch.tensor([i.lighting_encoded for i in items]) if ldr else None,
        encoded_ldr=torch.stack(ldr) if ldr else None,
        encoded_hdr=torch.stack(hdr) if hdr else None,
        input_masks=torch.stack([i.input_alpha for i in items])  # type: ignore[misc]
        if all(i.input_alpha is not None for i in items)
        else None,
    )


def sampling_model(
    model: NeuralGafferModel, unet: UNet2DConditionModel, ema: EMAModel | None
) -> NeuralGafferModel:
    """A copy of the trained UNet (with the EMA weights when given) beside the shared frozen parts."""
    unet_copy = copy.deepcopy(unet)
    if ema is not None:
        ema.copy_to(unet_copy)
    unet_copy.eval()
    return NeuralGafferModel(
        config=model.config, unet=unet_copy, vae=model.vae, image_encoder=model.image_encoder
    )


@torch.no_grad()
def validate(
    model: NeuralGafferModel,
    valset: ValidationSet,
    config: ValidationConfig,
    *,
    step: int,
    compat: LightingCompat,
    device: torch.device,
    dtype: str = "float32",
    sheet_dir: Path | None = None,
) -> ValidationResult:
    """Relight every pair of `valset` and score it.

    Args:
        model: the networks to sample with (see `sampling_model`); moved to `device`/`dtype`.
        valset: the held-out pairs.
        config: steps, guidance, batch size, seed.
        step: training step (for the result and the sheet's file name).
        compat: lighting encoding used in training.
        device: where to sample.
        dtype: "float32", "float16" or "bfloat16".
        sheet_dir: write `step-XXXXXXXX.png` (rows: input | prediction | ground truth) here.

    Returns:
        The scores.
    """
    pipe = RelightPipeline(model, RuntimeConfig(device=str(device), dtype=dtype))  # type: ignore[arg-type]
    sampling = SamplingConfig(
        num_inference_steps=config.num_inference_steps, guidance_scale=config.guidance_scale
    )
    res = model.config.resolution
    # every pair's maps at once (N is small): environment maps encoded, the authors' maps as they are
    ldr_all, hdr_all = batch_lighting(
        valset.envmaps,
        valset.w2c_blender,
        encoded=valset.lighting_encoded,
        encoded_ldr=valset.encoded_ldr,
        encoded_hdr=valset.encoded_hdr,
        size=res,
        compat=compat,
        device=device,
    )
    batches = relight_in_batches(
        pipe,
        valset.input_images,
        LightingMaps(ldr=ldr_all, hdr=hdr_all),
        sampling,
        seeds=[config.seed + i for i in range(valset.size)],
        batch_size=config.batch_size,
        mask=valset.input_masks,
        device=device,
    )
    pred = torch.cat([b.output.images.float().cpu() for b in batches])
    # 8-bit like saved predictions (the authors score PNGs); the pipeline's images are in [0, 1]
    pred = quantize_8bit(pred)
    p = psnr(pred, valset.target_images)
    p_id = psnr(valset.input_images, valset.target_images)
    sheet = None
    if sheet_dir is not None:
        sheet = _write_sheet(sheet_dir / f"step-{step:08d}.png", valset, pred)
    return ValidationResult(
        step=step,
        psnr=float(p.mean()),
        psnr_identity=float(p_id.mean()),
        psnr_per_item=tuple(float(v) for v in p),
        psnr_identity_per_item=tuple(float(v) for v in p_id),
        sheet=sheet,
    )


def sheet_array(valset: ValidationSet, pred: Tensor, max_rows: int = 8) -> np.ndarray:
    """`[rows * H, 3 * W, 3]` uint8: input | prediction | ground truth per row."""
    n = min(valset.size, max_rows)
    rows = [
        torch.cat([valset.input_images[i], pred[i], valset.target_images[i]], dim=2)
        for i in range(n)
    ]
    return to_uint8(torch.cat(rows, dim=1))


def _write_sheet(path: Path, valset: ValidationSet, pred: Tensor) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png(path, sheet_array(valset, pred))


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
