"""Volume rendering of a `TensoRFVM`, and the frozen-density sample-weight cache used for relighting.

Ray marching follows TensoRF: samples start where the ray enters the box (clamped to [near, far]) and
advance by `step_size` (with one uniform jitter per ray in training); samples outside the box or where
the alpha mask is empty get no density (empty-space skipping: the density network never sees them).
With sigma_i and spacing delta_i (times `distance_scale`):

    alpha_i = 1 - exp(-sigma_i delta_i),   T_i = prod_{j<i} (1 - alpha_j),   w_i = alpha_i T_i,
    C = sum_i w_i c_i + (1 - sum_i w_i) * background

and the appearance network runs only where w_i > `weight_threshold`.

Relighting freezes the density (paper §3.3), so the weights never change: `build_weight_cache` stores,
per ray, only the samples with w_i > threshold (position and weight, CSR layout), and
`render_cached` evaluates the appearance at those points alone, equal to `render_rays` without jitter.
"""

from dataclasses import dataclass

import torch
from jaxtyping import Float, Int
from torch import Tensor

from gaffer_nerf.cameras import RayBundle
from gaffer_nerf.fields.tensorf import TensoRFVM


@dataclass(frozen=True, kw_only=True)
class RenderOutput:
    """Per-ray render.

    Attributes:
        rgb: `[N, 3]` colour in [0, 1], composited over the background.
        accumulation: `[N]` opacity sum_i w_i.
        depth: `[N]` expected ray distance sum_i w_i t_i.
    """

    rgb: Float[Tensor, "N 3"]
    accumulation: Float[Tensor, " N"]
    depth: Float[Tensor, " N"]


@dataclass(frozen=True, kw_only=True)
class _March:
    xyz: Tensor  # [N, S, 3]
    t: Tensor  # [N, S]
    weights: Tensor  # [N, S]
    accumulation: Tensor  # [N]


def _march(
    field: TensoRFVM, rays: RayBundle, *, jitter: bool, generator: torch.Generator | None
) -> _March:
    """Sample along rays, evaluate density where the box and the alpha mask allow, get weights."""
    o, d = rays.origins_world, rays.dirs_world
    n_rays, n_samples = o.shape[0], field.num_samples
    step = field.step_size
    near, far = field.scene.near, field.scene.far
    vec = torch.where(d == 0, torch.full_like(d, 1e-6), d)
    rate_a = (field.aabb[1] - o) / vec
    rate_b = (field.aabb[0] - o) / vec
    t_min = torch.minimum(rate_a, rate_b).amax(dim=-1).clamp(min=near, max=far)  # [N]
    rng = torch.arange(n_samples, device=o.device, dtype=o.dtype)[None].expand(n_rays, -1)
    if jitter:
        rng = rng + torch.rand((n_rays, 1), generator=generator, device=o.device, dtype=o.dtype)
    t = t_min[:, None] + step * rng  # [N, S]
    xyz = o[:, None] + d[:, None] * t[..., None]  # [N, S, 3]
    valid = ~((xyz < field.aabb[0]) | (xyz > field.aabb[1])).any(dim=-1) & (t <= far)  # [N, S]
    if field.alpha_volume is not None and bool(valid.any()):
        keep = field.sample_alpha_mask(xyz[valid]) > 0
        valid = valid.clone()
        valid[valid.clone()] = keep
    sigma = torch.zeros((n_rays, n_samples), device=o.device, dtype=o.dtype)
    if bool(valid.any()):
        sigma = sigma.masked_scatter(valid, field.density(xyz[valid]))
    dists = torch.cat([t[:, 1:] - t[:, :-1], torch.zeros_like(t[:, :1])], dim=-1)
    alpha = 1.0 - torch.exp(-sigma * dists * field.config.distance_scale)
    # T_i = prod_{j<i} (1 - alpha_j); the 1e-10 keeps cumprod differentiable at alpha = 1 (TensoRF)
    trans = torch.cumprod(
        torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10], dim=-1), dim=-1
    )[:, :-1]
    weights = alpha * trans
    return _March(xyz=xyz, t=t, weights=weights, accumulation=weights.sum(dim=-1))


def render_rays(
    field: TensoRFVM,
    rays: RayBundle,
    *,
    jitter: bool = False,
    generator: torch.Generator | None = None,
) -> RenderOutput:
    """Render rays through the full field (density and appearance), differentiably.

    Args:
        field: the radiance field.
        rays: `N` rays with unit directions.
        jitter: one uniform sample offset per ray (training).
        generator: RNG for the jitter.

    Returns:
        `RenderOutput` with `[N, 3]` colour in [0, 1].
    """
    m = _march(field, rays, jitter=jitter, generator=generator)
    w = m.weights
    app = w > field.config.weight_threshold  # [N, S]
    rgb_samples = torch.zeros((*w.shape, 3), device=w.device, dtype=w.dtype)
    if bool(app.any()):
        dirs = rays.dirs_world[:, None].expand(-1, w.shape[1], -1)
        rgb_samples = rgb_samples.masked_scatter(
            app[..., None], field.radiance(m.xyz[app], dirs[app])
        )
    rgb = (w[..., None] * rgb_samples).sum(dim=1)
    if field.scene.white_background:
        rgb = rgb + (1.0 - m.accumulation[:, None])
    return RenderOutput(
        rgb=rgb.clamp(0.0, 1.0), accumulation=m.accumulation, depth=(w * m.t).sum(dim=-1)
    )


@torch.no_grad()
def render_rays_chunked(field: TensoRFVM, rays: RayBundle, chunk: int = 8192) -> RenderOutput:
    """`render_rays` without gradients and jitter, `chunk` rays at a time (evaluation, full images)."""
    outs = [
        render_rays(field, rays.select(slice(s, s + chunk))) for s in range(0, len(rays), chunk)
    ]
    return RenderOutput(
        rgb=torch.cat([o.rgb for o in outs]),
        accumulation=torch.cat([o.accumulation for o in outs]),
        depth=torch.cat([o.depth for o in outs]),
    )


@dataclass(frozen=True, kw_only=True)
class SampleWeightCache:
    """Per-ray sample positions and weights of a frozen density, in CSR layout.

    Attributes:
        xyz_world: `[M, 3]` sample positions with weight above the threshold, grouped by ray.
        weights: `[M]` their rendering weights w_i.
        ray_offsets: `[N + 1]` samples of ray r are `ray_offsets[r] : ray_offsets[r + 1]`.
        dirs_world: `[N, 3]` unit ray directions.
        background: `[N]` background weight 1 - sum_i w_i (over all samples, as the full renderer).
        white_background: whether the background is white (else black).
    """

    xyz_world: Float[Tensor, "M 3"]
    weights: Float[Tensor, " M"]
    ray_offsets: Int[Tensor, " N1"]
    dirs_world: Float[Tensor, "N 3"]
    background: Float[Tensor, " N"]
    white_background: bool

    @property
    def num_rays(self) -> int:
        """N."""
        return int(self.dirs_world.shape[0])

    @property
    def num_samples(self) -> int:
        """M, the samples the appearance network sees for all N rays."""
        return int(self.weights.shape[0])

    def nbytes(self) -> int:
        """Memory held by the cache."""
        return sum(
            t.numel() * t.element_size()
            for t in (
                self.xyz_world,
                self.weights,
                self.ray_offsets,
                self.dirs_world,
                self.background,
            )
        )

    def gather(self, ray_ids: Int[Tensor, " K"]) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Samples of the chosen rays: `(xyz [m, 3], dirs [m, 3], weights [m], local_ray [m])`."""
        ids = ray_ids.to(self.ray_offsets.device)
        start = self.ray_offsets[ids]
        counts = self.ray_offsets[ids + 1] - start  # [K]
        local = torch.repeat_interleave(torch.arange(ids.shape[0], device=ids.device), counts)
        first = (
            torch.cumsum(counts, 0) - counts
        )  # position of each ray's first sample in the output
        within = torch.arange(local.shape[0], device=ids.device) - first[local]
        idx = start[local] + within
        return self.xyz_world[idx], self.dirs_world[ids][local], self.weights[idx], local


@torch.no_grad()
def build_weight_cache(field: TensoRFVM, rays: RayBundle, chunk: int = 8192) -> SampleWeightCache:
    """March every ray once through the frozen density and keep the samples that matter.

    Args:
        field: the field whose density is frozen from now on.
        rays: all rays the relighting will render (e.g. every pixel of every training view).
        chunk: rays per marching call.

    Returns:
        The cache; `render_cached` on it equals `render_rays` (no jitter) on the same rays.
    """
    xyz, weights, counts, background = [], [], [], []
    thr = field.config.weight_threshold
    for s in range(0, len(rays), chunk):
        m = _march(field, rays.select(slice(s, s + chunk)), jitter=False, generator=None)
        keep = m.weights > thr  # [n, S], row-major = grouped by ray
        xyz.append(m.xyz[keep])
        weights.append(m.weights[keep])
        counts.append(keep.sum(dim=1))
        background.append(1.0 - m.accumulation)
    counts_all = torch.cat(counts)
    offsets = torch.cat([counts_all.new_zeros(1), torch.cumsum(counts_all, 0)])
    return SampleWeightCache(
        xyz_world=torch.cat(xyz),
        weights=torch.cat(weights),
        ray_offsets=offsets,
        dirs_world=rays.dirs_world.clone(),
        background=torch.cat(background),
        white_background=field.scene.white_background,
    )


def render_cached(
    field: TensoRFVM, cache: SampleWeightCache, ray_ids: Int[Tensor, " K"]
) -> Float[Tensor, "K 3"]:
    """Colour of cached rays: appearance only, differentiable w.r.t. the appearance parameters.

    Args:
        field: the field (its appearance may have changed since the cache was built; its density not).
        cache: from `build_weight_cache`.
        ray_ids: `[K]` indices into the cached rays.

    Returns:
        `[K, 3]` colour in [0, 1].
    """
    xyz, dirs, w, local = cache.gather(ray_ids)
    k = int(ray_ids.shape[0])
    rgb = torch.zeros((k, 3), device=cache.weights.device, dtype=cache.weights.dtype)
    if xyz.shape[0] > 0:
        rgb = rgb.index_add(0, local, w[:, None] * field.radiance(xyz, dirs))
    if cache.white_background:
        rgb = rgb + cache.background[ray_ids.to(cache.background.device)][:, None]
    return rgb.clamp(0.0, 1.0)
