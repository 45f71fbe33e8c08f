"""Stage 2 (paper §3.3, Eq. 3): refine the appearance with the diffusion guidance loss, or SDS.

Each step renders one random training view in full (from the frozen-density cache, with gradients),
and either
- "guidance" (optionally toward the render times the model's change of shading,
  `Stage2Config.target_detail="transfer"`, rather than the model's view itself):
  encodes it, noises it to t* (0.4 -> 0.05, exponential), DDIM-denoises with the model's
  sampling (`DiffusionGuide.sampling`: steps, CFG, mirror average) and that view's conditioning, decodes, and applies w1 L1 + w2 perceptual between the render and the result; or
- "sds": backpropagates the score-distillation gradient through the VAE encoder (the baseline).
All learning rates are multiplied by `lr_gamma` (0.1^(1/200)) after every step, as the authors do.
"""

import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from gaffer_nerf.configs import Stage2Config
from gaffer_nerf.errors import NonFiniteError
from gaffer_nerf.fields.tensorf import TensoRFVM
from gaffer_nerf.guidance.diffusion import DiffusionGuide, ViewConditions, t_star
from gaffer_nerf.guidance.perceptual import PerceptualLoss
from gaffer_nerf.relight._common import StageReport, appearance_optimizer
from gaffer_nerf.relight.detail import transfer_shading
from gaffer_nerf.rendering import SampleWeightCache, render_cached


def image_tv(x: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of neighbouring pixels of `[B, 3, H, W]` (the authors' extra term)."""
    return (x[..., 1:, :] - x[..., :-1, :]).abs().mean() + (x[..., 1:] - x[..., :-1]).abs().mean()


def _model_alpha(
    cache: SampleWeightCache,
    ids: torch.Tensor,
    image_size: tuple[int, int],
    guide: DiffusionGuide,
    view: int,
    conditions: ViewConditions,
) -> torch.Tensor:
    """The field's opacity along view `view`'s rays, cropped and resized as the model sees the view
    (`[1, R, R]`; the crop's white padding is taken as background)."""
    h, w = image_size
    background = cache.background[ids].reshape(1, 1, h, w).expand(1, 3, h, w)
    # clamped: the antialiased resize can overshoot [0, 1] by a rounding step
    return (1.0 - guide.model_views(background.float(), [view], conditions.framing)[:, 0]).clamp(
        0.0, 1.0
    )


def run_stage2(
    field: TensoRFVM,
    cache: SampleWeightCache,
    image_size: tuple[int, int],
    guide: DiffusionGuide,
    conditions: ViewConditions,
    perceptual: PerceptualLoss,
    config: Stage2Config,
    *,
    generator: torch.Generator | None = None,
    progress: bool = False,
    callback: Callable[[int, float], None] | None = None,
) -> StageReport:
    """Optimise the appearance of `field` in place with the Stage-2 objective.

    Args:
        field: the radiance field (density frozen).
        cache: sample weights of the training rays, `V * H * W` rays in view-major order.
        image_size: (H, W) of the training views.
        guide: the diffusion model.
        conditions: the V training views' conditioning under the target lighting.
        perceptual: the perceptual term (may be unavailable: then L1 only).
        config: the Stage-2 settings.
        generator: CPU RNG for views, noise and SDS timesteps.
        progress: show a progress bar.
        callback: `callback(step, loss)` after every step.

    Returns:
        The stage's `StageReport` (with the t* of every step for the guidance loss).

    Raises:
        NonFiniteError: when the loss becomes NaN/Inf.
    """
    t0 = time.perf_counter()
    h, w = image_size
    hw = h * w
    views = conditions.num_views
    field.freeze_density()
    opt = appearance_optimizer(field, config.lr_grid, config.lr_network, config.betas)
    device = cache.weights.device
    losses, stars = [], []
    non_finite_before = guide.sds_non_finite
    bar = tqdm(range(config.iterations), disable=not progress, desc="stage 2", leave=False)
    for step in bar:
        v = int(torch.randint(0, views, (1,), generator=generator))
        ids = torch.arange(v * hw, (v + 1) * hw, device=device)
        render = render_cached(field, cache, ids).T.reshape(1, 3, h, w)  # [1, 3, H, W]
        x = guide.model_views(
            render, [v], conditions.framing
        )  # [1, 3, R, R], cropped as the inputs
        enc = conditions.encoded.select([v])
        mirrored = None if conditions.mirrored is None else conditions.mirrored.select([v])
        match config.loss:
            case "guidance":
                ts = t_star(step, config.iterations, config)
                stars.append(ts)
                target = guide.denoise_from(
                    x.detach(),
                    enc,
                    ts,
                    generator=generator,
                    encode_mode=config.encode_mode,
                    mirrored=mirrored,
                ).to(x)
                if config.target_detail == "transfer":  # the render's texture, the model's light
                    alpha = _model_alpha(cache, ids, (h, w), guide, v, conditions)
                    target = transfer_shading(
                        x.detach(), target, alpha, config.transfer_radius_px
                    ).to(x)
                loss = config.l1_weight * F.l1_loss(x, target)
                if config.perceptual_weight > 0 and perceptual.available:
                    loss = loss + config.perceptual_weight * perceptual(x, target)
            case "sds":
                loss = guide.sds_loss(x, enc, config, generator=generator, mirrored=mirrored)
                loss = loss.to(x.device)
        if config.image_tv_weight > 0:
            loss = loss + config.image_tv_weight * image_tv(x)
        if not bool(torch.isfinite(loss)):
            raise NonFiniteError(
                f"Stage 2 ({config.loss}) loss is {float(loss.detach())} at step {step}; lower the learning "
                "rates or, for SDS, `sds_weight`."
            )
        if loss.requires_grad:  # else the view holds no sample: nothing to fit
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        for g in opt.param_groups:
            g["lr"] *= config.lr_gamma
        losses.append(float(loss.detach()))
        if callback is not None:
            callback(step, losses[-1])
    bar.close()
    return StageReport(
        name="stage2",
        iterations=config.iterations,
        seconds=time.perf_counter() - t0,
        losses=tuple(losses),
        t_star=tuple(stars),
        loss_kind=config.loss,
        sds_non_finite=guide.sds_non_finite - non_finite_before,
    )
