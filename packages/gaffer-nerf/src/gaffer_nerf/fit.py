"""Fit a TensoRF VM field to multi-view images (TensoRF's training recipe, official implementation §6).

Per step: a random batch of training rays, jittered samples, loss = MSE + L1 x density-L1 (+ TV terms,
0 for synthetic scenes), Adam with exponential learning-rate decay to `lr_decay_ratio`. At the
`alpha_mask_at` iterations the alpha mask is rebuilt (the first one also shrinks the box to the occupied
region and switches the L1 weight; the second drops the rays that miss the box); at the `upsample_at`
iterations the factors are upsampled along a log-spaced voxel schedule and the optimiser is rebuilt at
the initial learning rates (TensoRF's `lr_upsample_reset`).

Two additions: the final resolution can come from the cameras' pixel footprint (`gaffer_nerf.sizing`),
and fitting can stop when the held-out PSNR stops improving (`EarlyStoppingConfig`).
"""

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from gaffer_nerf.cameras import RayBundle
from gaffer_nerf.configs import FitConfig
from gaffer_nerf.data.transforms import ViewSet
from gaffer_nerf.errors import ConfigError, NonFiniteError
from gaffer_nerf.fields.tensorf import GridSize, TensoRFVM, log_spaced_voxels, voxels_to_grid
from gaffer_nerf.rendering import render_rays, render_rays_chunked
from gaffer_nerf.sizing import GridSizing, choose_grid_sizing

logger = logging.getLogger(__name__)

StepCallback = Callable[[int, float], None]


@dataclass(frozen=True, kw_only=True)
class HeldoutScore:
    """Held-out PSNR at one iteration."""

    iteration: int
    psnr: float
    seconds: float


@dataclass(frozen=True, kw_only=True)
class FitReport:
    """What fitting did.

    Attributes:
        iterations_run: steps taken (fewer than configured when stopped early).
        stopped_early: whether the held-out PSNR plateau ended the fit.
        heldout: held-out PSNR history (empty without early stopping / held-out views).
        final_grid: voxels per axis at the end.
        grid_history: `(iteration, grid)` after every resize (shrink or upsample).
        sizing: the resolution decision.
        seconds: wall time.
        grid_bytes: memory of the factor grids at the end.
        final_train_loss: MSE of the last batch.
    """

    iterations_run: int
    stopped_early: bool
    heldout: tuple[HeldoutScore, ...]
    final_grid: GridSize
    grid_history: tuple[tuple[int, GridSize], ...]
    sizing: GridSizing
    seconds: float
    grid_bytes: int
    final_train_loss: float


@dataclass(frozen=True, kw_only=True)
class FitResult:
    """A fitted field and its report."""

    field: TensoRFVM
    report: FitReport


def _optimizer(field: TensoRFVM, config: FitConfig, scale: float = 1.0) -> torch.optim.Adam:
    return torch.optim.Adam(
        [
            {
                "params": field.density_parameters() + field.appearance_grid_parameters(),
                "lr": config.lr_grid * scale,
            },
            {"params": field.network_parameters(), "lr": config.lr_network * scale},
        ],
        betas=config.betas,
    )


def psnr_from_mse(mse: float) -> float:
    """10 log10(1 / mse) in dB for [0, 1] signals (inf at 0)."""
    return math.inf if mse <= 0 else -10.0 * math.log10(mse)


@torch.no_grad()
def heldout_psnr(field: TensoRFVM, rays: RayBundle, rgb: torch.Tensor, chunk: int = 8192) -> float:
    """PSNR of `render_rays` (no jitter) against `rgb` on the given rays."""
    out = render_rays_chunked(field, rays, chunk=chunk)
    return psnr_from_mse(float(F.mse_loss(out.rgb, rgb)))


def fit_tensorf(
    train: ViewSet,
    config: FitConfig,
    *,
    heldout: ViewSet | None = None,
    device: str | torch.device = "cpu",
    progress: bool = False,
    callback: StepCallback | None = None,
) -> FitResult:
    """Fit a TensoRF VM field to the training views.

    Args:
        train: training images (sRGB over white) and cameras.
        config: the recipe (`fit_preset("paper")` is the authors').
        heldout: held-out views for early stopping (needed when `config.early_stopping` is set).
        device: torch device.
        progress: show a progress bar.
        callback: called as `callback(iteration, loss)` after every step.

    Returns:
        `FitResult` with the field (on `device`) and a `FitReport`.

    Raises:
        CameraError: degenerate cameras (NaN poses, all centres coincident).
        ConfigError: early stopping without held-out views.
        NonFiniteError: the loss became NaN/Inf.
    """
    t0 = time.perf_counter()
    train.cameras.check_baseline()
    es = config.early_stopping
    if es is not None and heldout is None:
        raise ConfigError(
            "`config.early_stopping` is set but `heldout` is None; pass held-out views (e.g. the "
            "test split) or set `early_stopping=None`."
        )
    dev = torch.device(device)
    gen = torch.Generator().manual_seed(config.seed)
    rays = train.cameras.rays().to(dev)
    rgb = train.rgb_flat().to(dev)

    aabb0 = torch.tensor([config.scene.aabb_min, config.scene.aabb_max]).float()
    sizing = choose_grid_sizing(train.cameras, aabb0, config.sizing)
    final0 = sizing.final_voxels(aabb0, config)
    init_grid = voxels_to_grid(min(config.initial_voxels, final0), aabb0)
    field = TensoRFVM(config.tensorf, config.scene, init_grid, generator=gen).to(dev)
    n_up = len(config.upsample_at)
    voxel_schedule = (
        log_spaced_voxels(config.initial_voxels, config.final_voxels, n_up)
        if sizing.mode == "fixed"
        else []
    )

    optimizer = _optimizer(field, config)
    decay = config.lr_decay_ratio ** (1.0 / config.iterations)
    l1_weight = config.l1_weight_initial
    history: list[tuple[int, GridSize]] = [(0, field.grid_size)]
    scores: list[HeldoutScore] = []
    mask_grid: GridSize = field.grid_size

    eval_rays, eval_rgb = None, None
    if heldout is not None and es is not None:
        all_eval = heldout.cameras.rays()
        pick = torch.randperm(len(all_eval), generator=torch.Generator().manual_seed(1))
        pick = pick[: es.max_rays]
        eval_rays, eval_rgb = all_eval.select(pick).to(dev), heldout.rgb_flat()[pick].to(dev)

    best, since_best, stopped, loss_value = -math.inf, 0, False, math.nan
    it = 0
    bar = tqdm(range(1, config.iterations + 1), disable=not progress, desc="fit", leave=False)
    for it in bar:
        idx = torch.randint(0, len(rays), (config.batch_rays,), generator=gen).to(dev)
        out = render_rays(field, rays.select(idx), jitter=True, generator=_device_gen(gen, dev))
        mse = F.mse_loss(out.rgb, rgb[idx])
        loss = mse
        if l1_weight > 0:
            loss = loss + l1_weight * field.density_l1()
        if config.tv_weight_density > 0:
            loss = loss + config.tv_weight_density * field.tv_density()
        if config.tv_weight_appearance > 0:
            loss = loss + config.tv_weight_appearance * field.tv_appearance()
        if not bool(torch.isfinite(loss)):
            raise NonFiniteError(
                f"The fitting loss is {float(loss.detach())} at iteration {it}. Lower `lr_grid` / "
                "`lr_network`, or check the images for NaN."
            )
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        for group in optimizer.param_groups:
            group["lr"] *= decay
        loss_value = float(mse.detach())

        if it in config.alpha_mask_at:
            if math.prod(field.grid_size) < 256**3:
                mask_grid = field.grid_size
            info = field.update_alpha_mask(mask_grid)
            if it == config.alpha_mask_at[0]:
                if info.occupied_aabb is not None:
                    field.shrink(info.occupied_aabb)
                    history.append((it, field.grid_size))
                    optimizer = _optimizer(field, config, decay**it)
                l1_weight = config.l1_weight_rest
            elif it == config.alpha_mask_at[1] and info.occupied_aabb is not None:
                keep = _rays_hitting_box(rays, field.aabb)
                if bool(keep.any()):
                    rays, rgb = rays.select(keep), rgb[keep]
        if it in config.upsample_at:
            k = config.upsample_at.index(it)
            if sizing.mode == "fixed":
                target = voxels_to_grid(voxel_schedule[k], field.aabb)
            else:
                final = sizing.final_voxels(field.aabb, config)
                start = math.prod(history[0][1])
                n_vox = log_spaced_voxels(min(start, final), final, n_up)[k]
                target = voxels_to_grid(n_vox, field.aabb)
            field.upsample(target)
            history.append((it, field.grid_size))
            optimizer = _optimizer(field, config)  # lr reset, as TensoRF's lr_upsample_reset
        if callback is not None:
            callback(it, loss_value)
        if progress:
            bar.set_postfix(mse=f"{loss_value:.4g}", grid="x".join(map(str, field.grid_size)))

        if (
            es is not None
            and eval_rays is not None
            and eval_rgb is not None
            and it % es.eval_every == 0
        ):
            p = heldout_psnr(field, eval_rays, eval_rgb)
            scores.append(HeldoutScore(iteration=it, psnr=p, seconds=time.perf_counter() - t0))
            if p > best + es.min_delta_db:
                best, since_best = p, 0
            else:
                since_best += 1
            if since_best >= es.patience and it >= es.min_iterations:
                stopped = True
                logger.info("held-out PSNR plateaued at %.2f dB; stopping at %d", best, it)
                break
    bar.close()
    report = FitReport(
        iterations_run=it,
        stopped_early=stopped,
        heldout=tuple(scores),
        final_grid=field.grid_size,
        grid_history=tuple(history),
        sizing=sizing,
        seconds=time.perf_counter() - t0,
        grid_bytes=field.grid_memory_bytes(),
        final_train_loss=loss_value,
    )
    return FitResult(field=field, report=report)


def _device_gen(gen: torch.Generator, device: torch.device) -> torch.Generator | None:
    """The CPU generator for CPU runs; on other devices jitter uses the device's global RNG."""
    return gen if device.type == "cpu" else None


def _rays_hitting_box(rays: RayBundle, aabb: torch.Tensor) -> torch.Tensor:
    """`[N]` bool: the ray enters the box (TensoRF's `filtering_rays(bbox_only=True)`)."""
    d = torch.where(rays.dirs_world == 0, torch.full_like(rays.dirs_world, 1e-6), rays.dirs_world)
    a = (aabb[1] - rays.origins_world) / d
    b = (aabb[0] - rays.origins_world) / d
    t_near = torch.minimum(a, b).amax(dim=-1)
    t_far = torch.maximum(a, b).amin(dim=-1)
    return t_far > t_near
