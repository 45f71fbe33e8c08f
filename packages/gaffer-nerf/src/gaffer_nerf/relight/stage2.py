"""Stage 2 (paper §3.3, Eq. 3): refine the appearance with the diffusion guidance loss, or SDS.

Each step renders one random training view in full (from the frozen-density cache, with gradients),
and either
- "guidance" (optionally toward the render times the model's change of shading,
  `Stage2Config.target_detail="transfer"`, rather than the model's view itself):
  encodes it, noises it to t* (0.4 -> 0.05, exponential), DDIM-denoises with the model's
  sampling (`DiffusionGuide.sampling`: steps, CFG, mirror average) and that view's conditioning, decodes, and applies w1 L1 + w2 perceptual between the render and the result; or
- "sds": backpropagates the score-distillation gradient through the VAE encoder (the baseline).
All learning rates are multiplied by `lr_gamma` (0.1^(1/200)) after every step, as the authors do.

A guidance target that has lost the object is not followed. The target is the model's
partial denoise of the current render, so whatever it does to the object the next render inherits:
on a 128 px Cycles object fitted with the tiny preset, gaffer-tiny's denoise from t* = 0.4 of the
Stage-1 render returned the object as white, and the paper's Stage 2 (learning rate 0.02 for 500
steps) followed it step after step until the relit field rendered white (masked PSNR 6.4 dB vs 15.7
unrelit). A render drawn to white denoises to white, so
the loss kept falling while the object vanished. Such a step is skipped (counted in
`StageReport.skipped_targets`): a target whose object pixels, over the field's own opacity in the
model's frame, kept less than `TARGET_FADE_RATIO` of the render's contrast against the white
background (white-out) or of its brightness (black-out). A relighting that refines a Stage-1 result
moves far less than that in one step.
"""

import dataclasses
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from gaffer_nerf.configs import RelightConfig, Stage2Config
from gaffer_nerf.errors import NonFiniteError
from gaffer_nerf.fields.tensorf import TensoRFVM
from gaffer_nerf.guidance.diffusion import DiffusionGuide, ViewConditions, t_star
from gaffer_nerf.guidance.perceptual import PerceptualLoss
from gaffer_nerf.relight._common import StageReport, appearance_optimizer
from gaffer_nerf.relight.detail import transfer_shading
from gaffer_nerf.rendering import SampleWeightCache, render_cached

TARGET_FADE_RATIO = 0.5
"""A guidance target is followed only while its object keeps this fraction of the render's contrast
against white and of its brightness (see the module docstring)."""

MIN_OBJECT_SIGNAL = 0.02
"""Renders whose object has less contrast (brightness) than this have none to lose: not judged."""


def target_lost_object(
    render: torch.Tensor, target: torch.Tensor, alpha: torch.Tensor
) -> str | None:
    """ "white" or "black" when `target` lost the object `render` shows, else None.

    Args:
        render: `[B, 3, R, R]` the rendered view as the model sees it.
        target: `[B, 3, R, R]` the model's target for it.
        alpha: `[B, R, R]` the field's opacity in the same frame; the object is where it exceeds 0.5.
    """
    obj = (alpha > 0.5)[:, None].expand_as(render)
    if not bool(obj.any()):
        return None
    r, t = render[obj].float(), target[obj].float()
    contrast_r = float((1.0 - r).mean())
    if contrast_r > MIN_OBJECT_SIGNAL and float((1.0 - t).mean()) < TARGET_FADE_RATIO * contrast_r:
        return "white"
    bright_r = float(r.mean())
    if bright_r > MIN_OBJECT_SIGNAL and float(t.mean()) < TARGET_FADE_RATIO * bright_r:
        return "black"
    return None


def stage2_for_model(config: RelightConfig, model_steps: int) -> tuple[RelightConfig, str | None]:
    """`config` without its guidance Stage 2 when the model samples in one step, and why.

    Stage 2's target is the model's denoise of the render from a partial noise level t* (0.4 ->
    0.05, paper §3.3), which presumes a model that denoises from every level. A model whose own
    sampling (its folder's `DefaultSampling`) is one step from pure noise has learned only that
    step: gaffer-tiny's denoise from any lower start scores below its input
    (benchmarks/results/diffusion_quality.json: 1 DDIM step 18.44 dB object PSNR, 2 steps 9.31,
    the unrelit input 11.21), and from t* = 0.4 it returned a small field's object white. The one
    strength at which such a model relights, t* = 1, ignores the render and gives back Stage 1's
    own targets, so Stage 2 has nothing to add: the run falls back to the Stage-1 targets. A
    Stage-2-only run (no Stage 1) and SDS are kept: they are explicit choices.

    Args:
        config: the run's config.
        model_steps: the model's own number of sampling steps (`DefaultSampling.num_inference_steps`).

    Returns:
        The config (Stage 2 dropped or unchanged) and the reason it was dropped (None: kept).

    Example:
        >>> from gaffer_nerf.configs import relight_preset
        >>> cfg, why = stage2_for_model(relight_preset("paper"), 1)
        >>> cfg.stage2 is None, why is not None
        (True, True)
        >>> stage2_for_model(relight_preset("paper"), 50)[1] is None
        True
    """
    s2 = config.stage2
    if model_steps > 1 or s2 is None or s2.loss != "guidance" or config.stage1 is None:
        return config, None
    why = (
        "the model samples in one step from pure noise, so its partial denoise from "
        f"t* = {s2.t_start:g} -> {s2.t_end:g} is no relighting: Stage 2 is off and the field keeps "
        "its Stage-1 targets (force it with `--ablation full`)"
    )
    return dataclasses.replace(config, stage2=None), why


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
    skipped = 0
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
        follow = True
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
                alpha = _model_alpha(cache, ids, (h, w), guide, v, conditions)
                # a target that erased the object is not a relighting of it: not followed
                follow = target_lost_object(x.detach(), target, alpha) is None
                skipped += 0 if follow else 1
                if config.target_detail == "transfer":  # the render's texture, the model's light
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
        if follow and loss.requires_grad:  # else no sample in the view, or a lost target
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
        skipped_targets=skipped,
    )
