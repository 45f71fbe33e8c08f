"""Volume rendering against closed forms, and the frozen-density cache against the full renderer."""

import math

import torch

from gaffer_nerf.cameras import RayBundle
from gaffer_nerf.configs import SceneBoxConfig, TensoRFConfig
from gaffer_nerf.fields import TensoRFVM
from gaffer_nerf.fit import FitResult
from gaffer_nerf.rendering import (
    build_weight_cache,
    render_cached,
    render_rays,
    render_rays_chunked,
)

CFG = TensoRFConfig(
    density_ranks=(1, 1, 1), appearance_ranks=(2, 2, 2), appearance_dim=4, mlp_hidden=8
)
SCENE = SceneBoxConfig(aabb_min=(-1.0, -1.0, -1.0), aabb_max=(1.0, 1.0, 1.0), near=0.0, far=10.0)


def _constant_density_field(feature: float) -> TensoRFVM:
    """sigma = softplus(feature - 10) everywhere: plane=1, lines = feature on one pair, 0 elsewhere."""
    field = TensoRFVM(CFG, SCENE, (5, 5, 5), generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        for i in range(3):
            field.density_planes[i].fill_(1.0 if i == 0 else 0.0)
            field.density_lines[i].fill_(feature if i == 0 else 0.0)
    return field


def test_constant_density_slab_matches_beer_lambert() -> None:
    feature = 10.5
    field = _constant_density_field(feature)
    sigma = math.log1p(math.exp(feature - 10.0))
    rays = RayBundle(
        origins_world=torch.tensor([[0.0, 0.0, -3.0]]), dirs_world=torch.tensor([[0.0, 0.0, 1.0]])
    )
    with torch.no_grad():
        out = render_rays(field, rays)
    # the ray crosses the box over length 2 (scaled by distance_scale); the sampled sum telescopes to
    # 1 - exp(-sigma * scale * covered length), covered = n_inside * step
    step = field.step_size
    n_inside = math.floor(2.0 / step + 1e-6) + 1
    covered = (n_inside - 1) * step
    expected = 1.0 - math.exp(-sigma * CFG.distance_scale * covered)
    assert abs(float(out.accumulation[0]) - expected) < 1e-4
    assert bool(((out.rgb >= 0) & (out.rgb <= 1)).all())


def test_empty_field_renders_the_white_background(rng: torch.Generator) -> None:
    field = _constant_density_field(-30.0)
    rays = RayBundle(
        origins_world=torch.randn(64, 3, generator=rng) * 0.1 + torch.tensor([0.0, 0.0, -3.0]),
        dirs_world=torch.nn.functional.normalize(
            torch.randn(64, 3, generator=rng) * 0.1 + torch.tensor([0.0, 0, 1]), dim=-1
        ),
    )
    out = render_rays_chunked(field, rays, chunk=16)
    torch.testing.assert_close(out.rgb, torch.ones(64, 3), atol=1e-4, rtol=0)
    assert float(out.accumulation.max()) < 1e-4


def test_jitter_changes_samples_but_not_the_expectation(fitted: FitResult, scene) -> None:
    field = fitted.field
    rays = scene.train.cameras.rays([0]).select(torch.arange(0, 4096, 7))
    with torch.no_grad():
        a = render_rays(field, rays)
        b = render_rays(field, rays, jitter=True, generator=torch.Generator().manual_seed(3))
    assert not torch.equal(a.rgb, b.rgb)
    assert float((a.rgb - b.rgb).abs().mean()) < 0.05


def test_cache_equals_full_render_and_is_differentiable(fitted: FitResult, scene) -> None:
    field = fitted.field
    rays = scene.train.cameras.rays([0, 3])
    cache = build_weight_cache(field, rays, chunk=1000)
    assert cache.num_rays == len(rays)
    # empty-space skipping: far fewer samples than rays x samples-per-ray
    assert cache.num_samples < 0.25 * len(rays) * field.num_samples
    ids = torch.randperm(len(rays), generator=torch.Generator().manual_seed(0))[:777]
    full = render_rays_chunked(field, rays.select(ids)).rgb
    cached = render_cached(field, cache, ids)
    torch.testing.assert_close(cached.detach(), full, atol=2e-5, rtol=1e-5)
    cached.sum().backward()
    grads = [p.grad for p in field.network_parameters()]
    assert all(g is not None and bool(torch.isfinite(g).all()) for g in grads)
    field.zero_grad(set_to_none=True)


def test_cache_gather_reference() -> None:
    field = _constant_density_field(11.0)
    rays = RayBundle(
        origins_world=torch.tensor([[0.0, 0, -3], [0.0, 0, -3], [5.0, 5, -3]]),
        dirs_world=torch.tensor([[0.0, 0, 1], [0.0, 0.2, 0.96**0.5], [0.0, 0, 1]]),
    )
    cache = build_weight_cache(field, rays)
    counts = (cache.ray_offsets[1:] - cache.ray_offsets[:-1]).tolist()
    assert counts[0] > 0 and counts[1] > 0 and counts[2] == 0  # the third ray misses the box
    _xyz, dirs, _w, local = cache.gather(torch.tensor([2, 1, 0]))
    assert local.tolist() == [1] * counts[1] + [2] * counts[0]  # positions in the requested ids
    torch.testing.assert_close(dirs[0], rays.dirs_world[1])
    assert float(cache.background[2]) == 1.0
