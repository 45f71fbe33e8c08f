"""TensoRF VM field: features against a plain reference twin, resizing, alpha mask, regularisers."""

import math

import pytest
import torch

from gaffer_nerf.configs import SceneBoxConfig, TensoRFConfig, fit_preset
from gaffer_nerf.errors import ConfigError
from gaffer_nerf.fields import (
    MAT_MODE,
    VEC_MODE,
    EmptyAlphaMaskWarning,
    TensoRFVM,
    finite_or_zero,
    log_spaced_voxels,
    positional_encoding,
    voxels_to_grid,
)

CFG = TensoRFConfig(
    density_ranks=(2, 3, 2), appearance_ranks=(3, 2, 4), appearance_dim=5, mlp_hidden=8
)
SCENE = SceneBoxConfig(aabb_min=(-1.0, -1.0, -1.0), aabb_max=(1.0, 1.0, 1.0))


def _field(grid=(5, 6, 7), seed=0) -> TensoRFVM:
    return TensoRFVM(CFG, SCENE, grid, generator=torch.Generator().manual_seed(seed))


def _interp1(values: torch.Tensor, u: float) -> torch.Tensor:
    """Linear interpolation of `[n]` samples at u in [-1, 1] with align_corners=True (reference)."""
    n = values.shape[-1]
    x = (u + 1) / 2 * (n - 1)
    i0 = min(math.floor(x), n - 2)
    f = x - i0
    return values[..., i0] * (1 - f) + values[..., i0 + 1] * f


def _reference_density_feature(field: TensoRFVM, p: torch.Tensor) -> float:
    """sum_i sum_r M_i^r(p[a], p[b]) v_i^r(p[c]), one point, written out (bilinear by hand)."""
    total = 0.0
    for i, (a, b) in enumerate(MAT_MODE):
        c = VEC_MODE[i]
        plane = field.density_planes[i][0].detach()  # [R, grid[b], grid[a]]
        line = field.density_lines[i][0, :, :, 0].detach()  # [R, grid[c]]
        rows = torch.stack(
            [_interp1(plane[:, j, :], float(p[a])) for j in range(plane.shape[1])], -1
        )
        m = _interp1(rows, float(p[b]))  # [R]
        v = _interp1(line, float(p[c]))
        total += float((m * v).sum())
    return total


def test_density_feature_matches_reference_twin(rng: torch.Generator) -> None:
    field = _field()
    pts = torch.rand(6, 3, generator=rng) * 2 - 1
    fast = field.density_feature(pts)
    ref = torch.tensor([_reference_density_feature(field, p) for p in pts])
    torch.testing.assert_close(fast, ref, atol=1e-5, rtol=1e-5)


def test_gradcheck_density_and_radiance(rng: torch.Generator) -> None:
    field = _field((4, 4, 4)).double()
    pts = (torch.rand(3, 3, generator=rng, dtype=torch.float64) * 1.6 - 0.8).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: field.density_feature(x), (pts,))
    d = torch.nn.functional.normalize(torch.randn(3, 3, generator=rng, dtype=torch.float64), dim=-1)
    assert torch.autograd.gradcheck(lambda x: field.radiance(x, d), (pts,))


def test_smoke_shapes_and_ranges(rng: torch.Generator) -> None:
    field = _field()
    x = torch.rand(10, 3, generator=rng) * 2 - 1
    d = torch.nn.functional.normalize(torch.randn(10, 3, generator=rng), dim=-1)
    sigma, rgb = field.density(x), field.radiance(x, d)
    assert sigma.shape == (10,) and bool((sigma >= 0).all())
    assert rgb.shape == (10, 3) and bool(((rgb >= 0) & (rgb <= 1)).all())
    assert field.appearance_feature(x).shape == (10, CFG.appearance_dim)
    assert positional_encoding(torch.zeros(4, 5), 3).shape == (4, 30)


def test_untrained_field_is_nearly_empty() -> None:
    # density_shift -10: softplus(-10) ~ 4.5e-5, so the box starts transparent (TensoRF's init)
    field = _field()
    with torch.no_grad():
        assert float(field.density(torch.zeros(50, 3)).max()) < 1e-3


def test_upsample_preserves_a_linear_field() -> None:
    field = _field((3, 3, 3))
    with torch.no_grad():  # factors linear in each coordinate: bilinear upsampling is exact
        for i in range(len(MAT_MODE)):
            gb, ga = field.density_planes[i].shape[2:]
            yy, xx = torch.meshgrid(
                torch.linspace(-1, 1, gb), torch.linspace(-1, 1, ga), indexing="ij"
            )
            field.density_planes[i][:] = (xx + 2 * yy)[None, None]
            field.density_lines[i][:] = torch.linspace(-1, 1, field.density_lines[i].shape[2])[
                None, None, :, None
            ]
    pts = torch.rand(20, 3, generator=torch.Generator().manual_seed(1)) * 2 - 1
    before = field.density_feature(pts)
    field.upsample((7, 9, 11))
    assert field.grid_size == (7, 9, 11)
    assert tuple(field.density_planes[0].shape) == (1, 2, 9, 7)
    assert tuple(field.density_lines[0].shape) == (1, 2, 11, 1)
    torch.testing.assert_close(field.density_feature(pts), before, atol=1e-5, rtol=1e-5)


def test_shrink_keeps_values_and_voxel_pitch() -> None:
    field = _field((9, 9, 9))
    pitch = field.units.clone()
    box = torch.tensor([[-0.5, -0.25, 0.0], [0.5, 0.75, 0.5]])
    pts = (
        torch.rand(20, 3, generator=torch.Generator().manual_seed(2)) * 0.5 * (box[1] - box[0])
        + box[0]
        + 0.1
    )
    d = torch.nn.functional.normalize(torch.ones(20, 3), dim=-1)
    sigma, rgb = field.density(pts), field.radiance(pts, d)
    field.shrink(box)
    torch.testing.assert_close(field.units, pitch)
    assert bool((field.aabb[0] <= box[0] + 1e-6).all()) and bool(
        (field.aabb[1] >= box[1] - 1e-6).all()
    )
    torch.testing.assert_close(field.density(pts), sigma, atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(field.radiance(pts, d), rgb, atol=1e-5, rtol=1e-4)


def test_alpha_mask_finds_a_blob_and_empty_mask_is_refused() -> None:
    field = _field((9, 9, 9))
    with pytest.warns(EmptyAlphaMaskWarning, match="empty"):
        info = field.update_alpha_mask()
    assert info.empty and field.alpha_volume is None
    with torch.no_grad():  # a positive blob around voxel (4, 4, 4) only
        for planes, lines in ((field.density_planes, field.density_lines),):
            for i in range(3):
                planes[i].zero_()
                lines[i].zero_()
                planes[i][0, 0, 3:6, 3:6] = 4.0
                lines[i][0, 0, 3:6, 0] = 4.0
    info = field.update_alpha_mask()
    assert not info.empty and 0 < info.occupied_fraction < 0.5
    assert info.occupied_aabb is not None
    assert bool((info.occupied_aabb[0] > -1).all()) and bool((info.occupied_aabb[1] < 1).all())
    field.requires_grad_(False)
    assert float(field.sample_alpha_mask(torch.zeros(1, 3))) == 1.0
    assert float(field.sample_alpha_mask(torch.full((1, 3), 0.95))) == 0.0


def test_regularisers_nan_guard_and_degenerate_planes() -> None:
    field = _field((2, 2, 2))
    assert torch.isfinite(field.tv_density()) and torch.isfinite(field.density_l1())
    field.shrink(torch.tensor([[-1.0] * 3, [-0.99] * 3]))  # 2 points per axis is the floor
    assert min(field.grid_size) >= 2
    with torch.no_grad():
        field.density_planes[0][0, 0, 0, 0] = float("nan")
        field.appearance_planes[1][0, 0, 0, 0] = float("inf")
    for value in (field.density_l1(), field.tv_density(), field.tv_appearance()):
        assert float(value.detach()) == 0.0
    x = torch.tensor(float("nan"), requires_grad=True)
    y = finite_or_zero(x * 2, "test")
    y.backward()
    assert float(y.detach()) == 0.0 and x.grad is not None


def test_tv_of_single_row_plane_is_finite() -> None:
    field = _field((4, 4, 4))
    field.density_planes[0] = torch.nn.Parameter(
        torch.randn(1, 2, 1, 4)
    )  # H = 1: TensoRF divides by 0
    assert torch.isfinite(field.tv_density())


def test_exceptions_and_grid_helpers() -> None:
    with pytest.raises(ConfigError, match="grid_size"):
        _field((1, 4, 4))
    with pytest.raises(ConfigError, match="density_ranks"):
        TensoRFConfig(density_ranks=(0, 1, 1))
    assert voxels_to_grid(1000, torch.tensor([[-1.0] * 3, [1.0] * 3])) == (10, 10, 10)
    g = voxels_to_grid(8 * 1000, torch.tensor([[0.0, 0, 0], [2.0, 1, 1]]))
    assert abs(g[0] - 2 * g[1]) <= 1  # cubic voxels (TensoRF truncates to integers)
    assert log_spaced_voxels(128**3, 300**3, 5)[-1] == 300**3
    assert fit_preset("tiny").tensorf.view_pe == 2


def test_to_moves_the_alpha_mask() -> None:
    field = _field((5, 5, 5))
    with torch.no_grad():
        for i in range(3):
            field.density_planes[i].fill_(3.0)
            field.density_lines[i].fill_(3.0)
    field.update_alpha_mask()
    assert field.alpha_volume is not None
    field.double()
    assert field.alpha_volume.dtype == torch.float64
