"""Stage 1 (paper §3.3, Eq. 2): fit the appearance to diffusion-relit training views with L2.

The density is frozen and cached as per-ray sample weights (`gaffer_nerf.rendering`), so each step
evaluates the appearance network at the cached samples of a random batch of training rays only.
"""

import time
from collections.abc import Callable

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor
from tqdm.auto import tqdm

from gaffer_nerf.configs import Stage1Config
from gaffer_nerf.errors import NonFiniteError, ShapeError
from gaffer_nerf.fields.tensorf import TensoRFVM
from gaffer_nerf.relight._common import StageReport, appearance_optimizer
from gaffer_nerf.rendering import SampleWeightCache, render_cached


def run_stage1(
    field: TensoRFVM,
    cache: SampleWeightCache,
    targets_rgb: Float[Tensor, "N 3"],
    config: Stage1Config,
    *,
    generator: torch.Generator | None = None,
    progress: bool = False,
    callback: Callable[[int, float], None] | None = None,
) -> StageReport:
    """Optimise the appearance of `field` in place so its cached rays match `targets_rgb`.

    Args:
        field: the radiance field (density frozen).
        cache: sample weights of the training rays.
        targets_rgb: `[N, 3]` relit colours of the same rays (same order as the cache).
        config: iterations, batch, learning rates.
        generator: RNG for the ray batches.
        progress: show a progress bar.
        callback: `callback(step, loss)` after every step.

    Returns:
        The stage's `StageReport`.

    Raises:
        ShapeError: when `targets_rgb` does not match the cache's rays.
        NonFiniteError: when the loss becomes NaN/Inf.
    """
    if tuple(targets_rgb.shape) != (cache.num_rays, 3):
        raise ShapeError("targets_rgb", tuple(targets_rgb.shape), f"[{cache.num_rays}, 3]")
    t0 = time.perf_counter()
    field.freeze_density()
    opt = appearance_optimizer(field, config.lr_grid, config.lr_network, config.betas)
    decay = config.lr_decay_ratio ** (1.0 / config.iterations)
    targets = targets_rgb.to(cache.weights.device)
    losses = []
    bar = tqdm(range(config.iterations), disable=not progress, desc="stage 1", leave=False)
    for step in bar:
        ids = torch.randint(0, cache.num_rays, (config.batch_rays,), generator=generator)
        ids = ids.to(cache.weights.device)
        loss = F.mse_loss(render_cached(field, cache, ids), targets[ids])
        if not bool(torch.isfinite(loss)):
            raise NonFiniteError(
                f"Stage 1 loss is {float(loss.detach())} at step {step}; lower `Stage1Config.lr_grid`."
            )
        if loss.requires_grad:  # else no ray of the batch has a sample: nothing to fit
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
        for g in opt.param_groups:
            g["lr"] *= decay
        losses.append(float(loss.detach()))
        if callback is not None:
            callback(step, losses[-1])
    bar.close()
    return StageReport(
        name="stage1",
        iterations=config.iterations,
        seconds=time.perf_counter() - t0,
        losses=tuple(losses),
        loss_kind="l2",
    )
