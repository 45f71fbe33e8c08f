"""The two-stage relighting of a fitted radiance field (paper §3.3) and its ablations (§4.4).

1. Freeze the density; march every training ray once and cache its sample weights.
2. Encode every training view with the target lighting in its camera frame (one batched pass).
3. Stage 1 (unless ablated): relight every training view with the diffusion model (batched), fit the
   appearance to them with L2 on random rays (or, with `Stage1Config.target_detail="transfer"`, to
   the input views times the model's change of shading: `gaffer_nerf.relight.detail`).
4. Stage 2 (unless ablated): refine with the guidance loss (or SDS) one full view per step.

After each stage the relit field's training views are checked against what they were fitted to
(`gaffer_nerf.relight.guard`): a white-out, black-out or NaN stops the run with
`RelightDivergedError` before anything is returned or written.

The input field is not modified: a deep copy is relit and returned.
"""

import copy
import time
import warnings
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor

from gaffer_nerf.configs import DiffusionSamplingConfig, RelightConfig
from gaffer_nerf.data.transforms import ViewSet
from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.fields.tensorf import TensoRFVM
from gaffer_nerf.guidance.diffusion import DiffusionGuide, TargetLighting
from gaffer_nerf.guidance.perceptual import PerceptualLoss
from gaffer_nerf.relight._common import StageReport
from gaffer_nerf.relight.detail import transfer_shading
from gaffer_nerf.relight.guard import check_renders_follow_targets
from gaffer_nerf.relight.stage1 import run_stage1
from gaffer_nerf.relight.stage2 import run_stage2
from gaffer_nerf.rendering import SampleWeightCache, build_weight_cache, render_cached


class NothingToRelightWarning(UserWarning):
    """The frozen density leaves no sample on any training ray: the relit field stays as it was."""


@dataclass(frozen=True, kw_only=True)
class RelightReport:
    """Timings and settings of a relighting run.

    Attributes:
        cache_seconds: marching the frozen density once for every training ray.
        cache_samples: samples kept (weight above threshold) for all training rays.
        cache_bytes: memory of the cache.
        encode_seconds: lighting maps + VAE/CLIP encoding of the training views.
        relight_views_seconds: diffusion relighting of the training views (0 when reused or skipped).
        stage1: Stage 1's report, or None when ablated.
        stage2: Stage 2's report, or None when ablated.
        perceptual_name: the perceptual network used in Stage 2 (None: unavailable / not used).
        perceptual_unavailable_reason: why there is none.
        total_seconds: everything above.
        sampling: the resolved diffusion sampling every stage used (`DiffusionGuide.sampling`).
        sampling_source: where its unset values came from (the model's suggestion, or the paper's).
    """

    cache_seconds: float
    cache_samples: int
    cache_bytes: int
    encode_seconds: float
    relight_views_seconds: float
    stage1: StageReport | None
    stage2: StageReport | None
    perceptual_name: str | None
    perceptual_unavailable_reason: str | None
    total_seconds: float
    sampling: DiffusionSamplingConfig | None = None
    sampling_source: str = ""


@dataclass(frozen=True, kw_only=True)
class RelightResult:
    """The relit field, the relit training views (Stage 1 targets) and the report.

    Attributes:
        field: the relit copy of the input field.
        relit_views: `[V, 3, R, R]` diffusion-relit training views as the model made them (their
            object-centred crops when the model frames views), or None without Stage 1.
        report: timings and settings.
    """

    field: TensoRFVM
    relit_views: Float[Tensor, "V 3 R R"] | None
    report: RelightReport


def relight_field(
    field: TensoRFVM,
    train: ViewSet,
    envmap: TargetLighting,
    guide: DiffusionGuide,
    config: RelightConfig,
    perceptual: PerceptualLoss,
    *,
    relit_views: Float[Tensor, "V 3 R R"] | None = None,
    stage1_targets: Float[Tensor, "V 3 H W"] | None = None,
    progress: bool = False,
) -> RelightResult:
    """Relight a fitted field under `envmap` with the diffusion prior.

    Args:
        field: the field fitted to the input-lighting views (left unchanged).
        train: the input-lighting training views and their cameras (the diffusion inputs).
        envmap: the target lighting, a `gaffer_envmap.EnvironmentMap` or `[He, We, 3]` radiance in
            Blender's world convention.
        guide: the diffusion model and its sampling settings (`guide.sampling`, already resolved
            against the model's suggestion; `config.diffusion` is not read here).
        config: stages, ablation, seeds.
        perceptual: Stage 2's perceptual term (`load_perceptual_loss()`; may be unavailable).
        relit_views: Stage 1 targets from an earlier run (same views, lighting and model) to reuse,
            as the model made them (`RelightResult.relit_views`: crops when the model frames views).
        stage1_targets: Stage 1 targets in the training views' own frames, fitted as they are
            (e.g. renders under the target lighting: an oracle); excludes `relit_views`.
        progress: show progress bars.

    Returns:
        `RelightResult`.

    Raises:
        ShapeError: when `relit_views` or `stage1_targets` does not match the training views.
        ConfigError: when both `relit_views` and `stage1_targets` are given.
        RelightDivergedError: a stage left the training views' renders white, black or NaN where
            the object is, against their targets (`gaffer_nerf.relight.guard`).
    """
    h, w = train.cameras.height, train.cameras.width
    if stage1_targets is not None:
        if relit_views is not None:
            raise ConfigError(
                "Pass `relit_views` (model crops) or `stage1_targets` (frames), not both."
            )
        if tuple(stage1_targets.shape) != (train.num_views, 3, h, w):
            raise ShapeError(
                "stage1_targets", tuple(stage1_targets.shape), f"[{train.num_views}, 3, {h}, {w}]"
            )
    t_all = time.perf_counter()
    gen = torch.Generator().manual_seed(config.seed)
    out = copy.deepcopy(field)
    out.freeze_density()
    device = out.aabb.device
    t0 = time.perf_counter()
    cache = build_weight_cache(out, train.cameras.rays().to(device))
    cache_s = time.perf_counter() - t0
    if cache.num_samples == 0:
        warnings.warn(
            "The fitted field is empty along every training ray (no object, or an empty alpha "
            "mask), so there is no appearance to relight; the stages run without updates and the "
            "field is returned unchanged. Check the fit (its alpha mask and held-out PSNR).",
            NothingToRelightWarning,
            stacklevel=2,
        )

    t0 = time.perf_counter()
    images = train.rgb_srgb.permute(0, 3, 1, 2).contiguous()  # [V, 3, H, W] channels-first boundary
    lighting = guide.lighting(envmap, train.cameras.w2c_blender())
    # the model sees each view as it was trained to (object-centred crops for gaffer-tiny): boxes
    # from the training alpha, else from the fitted field's opacity along the training rays
    alpha = train.alpha
    wants_transfer = (
        config.stage1 is not None
        and stage1_targets is None
        and config.stage1.target_detail == "transfer"
    )
    if alpha is None and (guide.sampling.crop_fraction is not None or wants_transfer):
        alpha = (1.0 - cache.background).reshape(train.num_views, h, w).cpu()
    framing = guide.framing(alpha)
    conditions = guide.encode_views(images, lighting, framing)
    encode_s = time.perf_counter() - t0

    relit_s, s1 = 0.0, None
    reference = images.float()  # what the renders follow: Stage 1's targets, else the inputs
    if config.stage1 is not None and stage1_targets is not None:
        reference = stage1_targets.float()
        targets_rgb = reference.permute(0, 2, 3, 1).reshape(-1, 3)
        s1 = run_stage1(out, cache, targets_rgb, config.stage1, generator=gen, progress=progress)
        _check(out, cache, reference, "stage 1")
    elif config.stage1 is not None:
        if relit_views is None:
            t0 = time.perf_counter()
            relit_views = guide.relight_views(conditions)
            relit_s = time.perf_counter() - t0
        elif relit_views.shape[0] != train.num_views or relit_views.shape[1] != 3:
            raise ShapeError(
                "relit_views", tuple(relit_views.shape), f"[{train.num_views}, 3, R, R]"
            )
        targets = relit_views.float()
        if framing is not None:  # the relit crops back into the frames (white around them)
            targets = framing.paste(targets, list(range(train.num_views)), images)
        elif tuple(targets.shape[2:]) != (h, w):
            targets = F.interpolate(
                targets, size=(h, w), mode="bilinear", antialias=True, align_corners=False
            )
        if wants_transfer and alpha is not None:  # the input's texture, the model's light
            targets = transfer_shading(images, targets, alpha, config.stage1.transfer_radius_px)
        targets_rgb = targets.permute(0, 2, 3, 1).reshape(-1, 3)  # view-major, row-major rays
        s1 = run_stage1(out, cache, targets_rgb, config.stage1, generator=gen, progress=progress)
        reference = targets
        _check(out, cache, reference, "stage 1")
    s2 = None
    if config.stage2 is not None:
        s2 = run_stage2(
            out,
            cache,
            (h, w),
            guide,
            conditions,
            perceptual,
            config.stage2,
            generator=gen,
            progress=progress,
        )
        _check(out, cache, reference, "stage 2")
    used_perceptual = (
        config.stage2 is not None
        and config.stage2.loss == "guidance"
        and config.stage2.perceptual_weight > 0
    )
    report = RelightReport(
        cache_seconds=cache_s,
        cache_samples=cache.num_samples,
        cache_bytes=cache.nbytes(),
        encode_seconds=encode_s,
        relight_views_seconds=relit_s,
        stage1=s1,
        stage2=s2,
        perceptual_name=perceptual.name if used_perceptual else None,
        perceptual_unavailable_reason=(
            perceptual.unavailable_reason if used_perceptual else "not used (no guidance loss)"
        ),
        total_seconds=time.perf_counter() - t_all,
        sampling=guide.sampling,
        sampling_source=guide.suggested.source,
    )
    return RelightResult(field=out, relit_views=relit_views, report=report)


@torch.no_grad()
def _check(
    field: TensoRFVM, cache: SampleWeightCache, reference: Tensor, after: str, chunk: int = 16384
) -> None:
    """Render every cached training ray and stop on a white-out, black-out or NaN (module doc)."""
    v, _, h, w = reference.shape
    rgb = torch.cat(
        [
            render_cached(field, cache, torch.arange(s, min(s + chunk, cache.num_rays)))
            for s in range(0, cache.num_rays, chunk)
        ]
    ).cpu()
    renders = rgb.reshape(v, h, w, 3).permute(0, 3, 1, 2)
    alpha = (1.0 - cache.background).reshape(v, h, w).cpu()
    check_renders_follow_targets(renders, reference.cpu(), alpha, after=after)
