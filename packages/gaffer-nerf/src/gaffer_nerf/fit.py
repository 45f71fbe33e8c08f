"""Fit a TensoRF VM field to multi-view images (TensoRF's training recipe, official implementation §6).

Per step: a random batch of training rays, jittered samples, loss = MSE + L1 x density-L1 (+ TV terms,
0 for synthetic scenes), Adam with exponential learning-rate decay to `lr_decay_ratio`. At the
`alpha_mask_at` iterations the alpha mask is rebuilt (the first one also shrinks the box to the occupied
region and switches the L1 weight; the second drops the rays that miss the box); at the `upsample_at`
iterations the factors are upsampled along a log-spaced voxel schedule and the optimiser is rebuilt at
the initial learning rates (TensoRF's `lr_upsample_reset`).

Three additions ("model no more than the scene needs"): the final resolution can come from the
cameras' pixel footprint (`gaffer_nerf.sizing`), fitting can stop when the held-out PSNR stops improving
(`EarlyStoppingConfig`), and the VM ranks can be chosen from a ladder by held-out PSNR
(`RankSelectionConfig`).
"""

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import torch
import torch.nn.functional as F
from tqdm.auto import tqdm

from gaffer_nerf.cameras import RayBundle
from gaffer_nerf.configs import FitConfig, Ranks, RankSelectionConfig
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
class RankRung:
    """One rung of the rank ladder: what its ranks cost and what they scored.

    Attributes:
        scale: the ladder multiplier.
        density_ranks: density components per plane/line pair.
        appearance_ranks: appearance components per plane/line pair.
        parameters: trainable parameters at the end of the fit (factors, basis matrix, MLP).
        memory_mib: their size in MiB.
        seconds: wall time of this rung's fit.
        iterations_run: steps taken (fewer than configured when stopped early).
        heldout_psnr: PSNR in dB on the held-out rays.
    """

    scale: float
    density_ranks: Ranks
    appearance_ranks: Ranks
    parameters: int
    memory_mib: float
    seconds: float
    iterations_run: int
    heldout_psnr: float


@dataclass(frozen=True, kw_only=True)
class RankSelectionReport:
    """The rank ladder as climbed: every rung fitted, and which one was kept.

    Attributes:
        rungs: the fitted rungs, smallest first (rungs above the stopping point are not fitted).
        chosen: index into `rungs` of the kept field.
        tolerance_db: the gain a larger rung needed to be worth it.
    """

    rungs: tuple[RankRung, ...]
    chosen: int
    tolerance_db: float

    @property
    def chosen_rung(self) -> RankRung:
        """The kept rung."""
        return self.rungs[self.chosen]


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
        seconds: wall time (of every rung, with rank selection).
        grid_bytes: memory of the factor grids at the end.
        final_train_loss: MSE of the last batch.
        rank_selection: the rank ladder, when `FitConfig.rank_selection` is set (the other fields
            describe the kept rung's fit).
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
    rank_selection: RankSelectionReport | None = None


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
        heldout: held-out views for early stopping and rank selection (needed when
            `config.early_stopping` or `config.rank_selection` is set).
        device: torch device.
        progress: show a progress bar.
        callback: called as `callback(iteration, loss)` after every step.

    Returns:
        `FitResult` with the field (on `device`) and a `FitReport`.

    Raises:
        CameraError: degenerate cameras (NaN poses, all centres coincident).
        ConfigError: early stopping or rank selection without held-out views.
        NonFiniteError: the loss became NaN/Inf.
    """
    train.cameras.check_baseline()
    for name in ("early_stopping", "rank_selection"):
        if getattr(config, name) is not None and heldout is None:
            raise ConfigError(
                f"`config.{name}` is set but `heldout` is None; pass held-out views (e.g. the "
                f"test split) or set `{name}=None`."
            )
    if config.rank_selection is not None and heldout is not None:
        return _fit_rank_ladder(
            train,
            config,
            config.rank_selection,
            heldout=heldout,
            device=torch.device(device),
            progress=progress,
            callback=callback,
        )
    return _fit_once(
        train,
        config,
        heldout=heldout,
        device=torch.device(device),
        progress=progress,
        callback=callback,
    )


def choose_rank_rung(psnrs: Sequence[float], tolerance_db: float) -> int | None:
    """Which rung of a rank ladder to keep, given the held-out PSNRs of the rungs fitted so far.

    The first rung k whose PSNR is within `tolerance_db` of rung k + 1's: a larger model would not
    pay for itself. None while every step up has gained more (fit the next rung, or, when none is
    left, keep the last: `len(psnrs) - 1`).

    Example:
        >>> choose_rank_rung([24.0, 27.0, 27.1], 0.25)
        1
        >>> choose_rank_rung([24.0, 27.0], 0.25) is None
        True
    """
    for k in range(len(psnrs) - 1):
        if psnrs[k] >= psnrs[k + 1] - tolerance_db:
            return k
    return None


def _fit_rank_ladder(
    train: ViewSet,
    config: FitConfig,
    selection: RankSelectionConfig,
    *,
    heldout: ViewSet,
    device: torch.device,
    progress: bool,
    callback: StepCallback | None,
) -> FitResult:
    """Fit each rung of the ladder, smallest first, until the held-out PSNR stops improving."""
    t0 = time.perf_counter()
    eval_rays, eval_rgb = _heldout_subset(heldout, selection.max_rays, device)
    base = config.tensorf
    results: list[FitResult] = []
    rungs: list[RankRung] = []
    seen: set[tuple[Ranks, Ranks]] = set()
    chosen: int | None = None
    for scale in selection.ladder:
        ranks = (
            selection.scaled_ranks(base.density_ranks, scale),
            selection.scaled_ranks(base.appearance_ranks, scale),
        )
        if ranks in seen:  # small base ranks: neighbouring multipliers can round alike
            continue
        seen.add(ranks)
        rung_config = replace(
            config,
            rank_selection=None,
            tensorf=replace(base, density_ranks=ranks[0], appearance_ranks=ranks[1]),
        )
        t_rung = time.perf_counter()
        res = _fit_once(
            train, rung_config, heldout=heldout, device=device, progress=progress, callback=callback
        )
        params = list(res.field.parameters())
        rungs.append(
            RankRung(
                scale=scale,
                density_ranks=ranks[0],
                appearance_ranks=ranks[1],
                parameters=sum(p.numel() for p in params),
                memory_mib=sum(p.numel() * p.element_size() for p in params) / 2**20,
                seconds=time.perf_counter() - t_rung,
                iterations_run=res.report.iterations_run,
                heldout_psnr=heldout_psnr(res.field, eval_rays, eval_rgb),
            )
        )
        results.append(res)
        logger.info(
            "ranks %s / %s: %.2f dB held out, %d parameters, %.1f s",
            ranks[0],
            ranks[1],
            rungs[-1].heldout_psnr,
            rungs[-1].parameters,
            rungs[-1].seconds,
        )
        chosen = choose_rank_rung([r.heldout_psnr for r in rungs], selection.tolerance_db)
        if chosen is not None:
            break
    if chosen is None:
        chosen = len(rungs) - 1
    kept = results[chosen]
    report = replace(
        kept.report,
        seconds=time.perf_counter() - t0,
        rank_selection=RankSelectionReport(
            rungs=tuple(rungs), chosen=chosen, tolerance_db=selection.tolerance_db
        ),
    )
    return FitResult(field=kept.field, report=report)


def _heldout_subset(
    heldout: ViewSet, max_rays: int, device: torch.device
) -> tuple[RayBundle, torch.Tensor]:
    """A fixed, seeded subset of at most `max_rays` held-out rays and their colours."""
    all_eval = heldout.cameras.rays()
    pick = torch.randperm(len(all_eval), generator=torch.Generator().manual_seed(1))[:max_rays]
    return all_eval.select(pick).to(device), heldout.rgb_flat()[pick].to(device)


def _fit_once(
    train: ViewSet,
    config: FitConfig,
    *,
    heldout: ViewSet | None,
    device: torch.device,
    progress: bool,
    callback: StepCallback | None,
) -> FitResult:
    """One fit with `config.tensorf`'s ranks (the body of `fit_tensorf`)."""
    t0 = time.perf_counter()
    es = config.early_stopping
    dev = device
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
        eval_rays, eval_rgb = _heldout_subset(heldout, es.max_rays, dev)

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
                # the fixed mode's schedule towards the grid the rule picks, ending exactly on it
                final = sizing.final_voxels(field.aabb, config)
                n_vox = log_spaced_voxels(min(config.initial_voxels, final), final, n_up)[k]
                last = k == n_up - 1
                target = (
                    sizing.final_grid(field.aabb, config)
                    if last
                    else voxels_to_grid(n_vox, field.aabb)
                )
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
