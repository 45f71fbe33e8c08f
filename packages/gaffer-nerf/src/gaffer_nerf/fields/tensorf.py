"""TensoRF with the vector-matrix (VM) decomposition (Chen et al., ECCV 2022), in plain PyTorch.

A feature at a normalised point p = (x, y, z) in [-1, 1]^3 is a sum over three plane/line pairs:

    f(p) = sum_{i in 0..2} sum_r  M_i^r(p[a_i], p[b_i]) * v_i^r(p[c_i])

with (a, b) = (0, 1), (0, 2), (1, 2) for the planes and c = 2, 1, 0 for the lines (TensoRF's `matMode`
and `vecMode`), bilinear / linear interpolation with `align_corners=True`. Density is
`softplus(f_sigma(p) + shift)` (shift -10); appearance is the concatenated per-component products
mapped by a basis matrix to `appearance_dim` features and shaded by `MLP_Fea` (feature and view-direction
positional encodings, two hidden ReLU layers, sigmoid).

Grid layout: plane i is a `[1, R, grid[b_i], grid[a_i]]` parameter, line i is `[1, R, grid[c_i], 1]`.
"""

import logging
import math
import warnings
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from jaxtyping import Float
from torch import Tensor, nn

from gaffer_nerf.configs import SceneBoxConfig, TensoRFConfig
from gaffer_nerf.errors import ConfigError, ShapeError

logger = logging.getLogger(__name__)

MAT_MODE: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (1, 2))
VEC_MODE: tuple[int, ...] = (2, 1, 0)

GridSize = tuple[int, int, int]


class EmptyAlphaMaskWarning(UserWarning):
    """The alpha mask found no occupied voxel; the previous mask and box are kept."""


def positional_encoding(x: Float[Tensor, "N C"], freqs: int) -> Float[Tensor, "N E"]:
    """NeRF positional encoding `[sin(2^k x), cos(2^k x)]`, k < freqs, E = 2 C freqs (TensoRF order).

    Example:
        >>> positional_encoding(torch.zeros(2, 3), 2).shape
        torch.Size([2, 12])
    """
    bands = 2.0 ** torch.arange(freqs, device=x.device, dtype=x.dtype)
    pts = (x[..., None] * bands).reshape(*x.shape[:-1], x.shape[-1] * freqs)
    return torch.cat([torch.sin(pts), torch.cos(pts)], dim=-1)


class FeatureMLP(nn.Module):
    """TensoRF's `MLPRender_Fea`: RGB from an appearance feature and a view direction.

    Input `[f, d, PE(f), PE(d)]`, two hidden ReLU layers of `hidden` units, sigmoid output; the last
    bias starts at 0 as in TensoRF.
    """

    def __init__(self, feature_dim: int, view_pe: int, feature_pe: int, hidden: int) -> None:
        super().__init__()
        self.view_pe = view_pe
        self.feature_pe = feature_pe
        in_dim = 2 * view_pe * 3 + 2 * feature_pe * feature_dim + 3 + feature_dim
        self.layers = nn.Sequential(
            nn.Linear(in_dim, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, 3),
        )
        last = self.layers[-1]
        if not isinstance(last, nn.Linear):  # nn.Sequential's indexing is typed as any Module
            raise TypeError(f"FeatureMLP's last layer is a {type(last).__name__}, not nn.Linear")
        nn.init.constant_(last.bias, 0.0)

    def forward(
        self, features: Float[Tensor, "N F"], dirs_world: Float[Tensor, "N 3"]
    ) -> Float[Tensor, "N 3"]:
        """RGB in [0, 1] (the colour space of the training images, sRGB for gaffer data)."""
        parts = [features, dirs_world]
        if self.feature_pe > 0:
            parts.append(positional_encoding(features, self.feature_pe))
        if self.view_pe > 0:
            parts.append(positional_encoding(dirs_world, self.view_pe))
        return torch.sigmoid(self.layers(torch.cat(parts, dim=-1)))


@dataclass(frozen=True, kw_only=True)
class AlphaMaskInfo:
    """What `TensoRFVM.update_alpha_mask` found.

    Attributes:
        occupied_fraction: fraction of grid points kept as occupied.
        occupied_aabb: `[2, 3]` world box of the occupied points, or None when none is occupied.
        empty: True when no point is occupied (the mask was then NOT installed).
    """

    occupied_fraction: float
    occupied_aabb: Tensor | None
    empty: bool


def _tv_2d(x: Tensor) -> Tensor:
    """TensoRF's TVLoss on `[1, R, H, W]`, skipping axes of size 1 (where TensoRF divides by zero)."""
    total = x.new_zeros(())
    if x.shape[2] > 1:
        total = total + 2 * (x[:, :, 1:] - x[:, :, :-1]).pow(2).mean()
    if x.shape[3] > 1:
        total = total + 2 * (x[:, :, :, 1:] - x[:, :, :, :-1]).pow(2).mean()
    return total


def finite_or_zero(value: Tensor, name: str) -> Tensor:
    """`value` if finite, else a zero that keeps the graph (the NaN guard of the regularisers).

    A non-finite regulariser would poison every parameter through Adam's moments; dropping the term for
    one step is the safe choice. Logged at WARNING.
    """
    if bool(torch.isfinite(value).all()):
        return value
    logger.warning("regulariser `%s` is %s; skipped for this step", name, value.detach().tolist())
    return torch.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0) * 0.0


class TensoRFVM(nn.Module):
    """A TensoRF VM radiance field over an axis-aligned box.

    Args:
        config: ranks, shading network and ray-marching settings.
        scene: initial bounding box, near/far and background.
        grid_size: initial voxels per axis (x, y, z).
        generator: RNG for the initialisation of the factors and the networks (None: torch's global RNG).

    Example:
        >>> from gaffer_nerf.configs import fit_preset
        >>> cfg = fit_preset("tiny")
        >>> f = TensoRFVM(cfg.tensorf, cfg.scene, (8, 8, 8))
        >>> f.density(torch.zeros(5, 3)).shape
        torch.Size([5])
    """

    aabb: Tensor  # [2, 3] buffer (registered in __init__): box min, box max
    density_planes: nn.ParameterList
    density_lines: nn.ParameterList
    appearance_planes: nn.ParameterList
    appearance_lines: nn.ParameterList

    def __init__(
        self,
        config: TensoRFConfig,
        scene: SceneBoxConfig,
        grid_size: GridSize,
        *,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.config = config
        self.scene = scene
        self.register_buffer("aabb", torch.tensor([scene.aabb_min, scene.aabb_max]).float())
        self.grid_size: GridSize = _check_grid("grid_size", grid_size)
        s = config.init_scale
        self.density_planes, self.density_lines = _init_vm(
            config.density_ranks, self.grid_size, s, generator
        )
        self.appearance_planes, self.appearance_lines = _init_vm(
            config.appearance_ranks, self.grid_size, s, generator
        )
        # nn.Linear initialises from torch's global RNG; with a generator, seed a forked global RNG
        # from it so that one seed fixes the whole field (and the caller's RNG state is untouched).
        with torch.random.fork_rng(devices=[], enabled=generator is not None):
            if generator is not None:
                torch.manual_seed(int(torch.randint(0, 2**62, (1,), generator=generator)))
            self.basis_mat = nn.Linear(
                sum(config.appearance_ranks), config.appearance_dim, bias=False
            )
            self.mlp = FeatureMLP(
                config.appearance_dim, config.view_pe, config.feature_pe, config.mlp_hidden
            )
        self.alpha_volume: Tensor | None = None  # [1, 1, Z, Y, X] in {0, 1}
        self.alpha_aabb: Tensor | None = None  # [2, 3]

    def _apply(self, fn, recurse=True):  # type: ignore[no-untyped-def]
        """Move/cast the alpha mask with the module (it is not a registered buffer: its shape varies)."""
        super()._apply(fn, recurse)
        if self.alpha_volume is not None and self.alpha_aabb is not None:
            self.alpha_volume = fn(self.alpha_volume)
            self.alpha_aabb = fn(self.alpha_aabb)
        return self

    # ------------------------------------------------------------------ geometry of the grid
    @property
    def aabb_size(self) -> Float[Tensor, " 3"]:
        """Box extent per axis."""
        return self.aabb[1] - self.aabb[0]

    @property
    def units(self) -> Float[Tensor, " 3"]:
        """Voxel pitch per axis (grid points sit on the box corners: extent / (n - 1))."""
        n = torch.tensor(self.grid_size, dtype=self.aabb.dtype, device=self.aabb.device)
        return self.aabb_size / (n - 1)

    @property
    def step_size(self) -> float:
        """Ray-march step: mean voxel pitch x `step_ratio`."""
        return float(self.units.mean()) * self.config.step_ratio

    @property
    def num_samples(self) -> int:
        """Samples per ray: enough steps to cross the box diagonal, capped by `max_samples`."""
        n = int(float(self.aabb_size.norm()) / self.step_size) + 1
        return min(n, self.config.max_samples)

    def normalize(self, xyz_world: Float[Tensor, "N 3"]) -> Float[Tensor, "N 3"]:
        """World points -> [-1, 1]^3 over the box."""
        return (xyz_world - self.aabb[0]) * (2.0 / self.aabb_size) - 1.0

    # ------------------------------------------------------------------ features
    def _vm_features(
        self, planes: nn.ParameterList, lines: nn.ParameterList, xyz_norm: Tensor
    ) -> tuple[list[Tensor], list[Tensor]]:
        n = xyz_norm.shape[0]
        plane_coef, line_coef = [], []
        for i, (a, b) in enumerate(MAT_MODE):
            c = VEC_MODE[i]
            coord_plane = xyz_norm[:, [a, b]].view(
                1, n, 1, 2
            )  # (x -> W = grid[a], y -> H = grid[b])
            coord_line = torch.stack(
                [torch.zeros_like(xyz_norm[:, c]), xyz_norm[:, c]], dim=-1
            ).view(1, n, 1, 2)
            # [1, R, N, 1] -> [R, N]
            plane_coef.append(F.grid_sample(planes[i], coord_plane, align_corners=True).view(-1, n))
            line_coef.append(F.grid_sample(lines[i], coord_line, align_corners=True).view(-1, n))
        return plane_coef, line_coef

    def density_feature(self, xyz_norm: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        """Raw density feature sum_i sum_r M_i^r v_i^r (before shift and softplus)."""
        planes, lines = self._vm_features(self.density_planes, self.density_lines, xyz_norm)
        return sum(((p * l).sum(dim=0) for p, l in zip(planes, lines, strict=True)),
                   xyz_norm.new_zeros(xyz_norm.shape[0]))  # fmt: skip

    def appearance_feature(self, xyz_norm: Float[Tensor, "N 3"]) -> Float[Tensor, "N F"]:
        """Appearance feature: basis matrix applied to the stacked component products."""
        planes, lines = self._vm_features(self.appearance_planes, self.appearance_lines, xyz_norm)
        prod = torch.cat(planes, dim=0) * torch.cat(lines, dim=0)  # [sum R, N]
        return self.basis_mat(prod.T)

    def density_from_feature(self, feature: Tensor) -> Tensor:
        """sigma = softplus(feature + density_shift) (TensoRF's `feature2density`, softplus mode)."""
        return F.softplus(feature + self.config.density_shift)

    def density(self, xyz_world: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        """Volume density sigma >= 0 at world points (no alpha mask applied)."""
        return self.density_from_feature(self.density_feature(self.normalize(xyz_world)))

    def radiance(
        self, xyz_world: Float[Tensor, "N 3"], dirs_world: Float[Tensor, "N 3"]
    ) -> Float[Tensor, "N 3"]:
        """Emitted colour in [0, 1] at world points seen along unit directions."""
        return self.mlp(self.appearance_feature(self.normalize(xyz_world)), dirs_world)

    # ------------------------------------------------------------------ parameter groups
    def density_parameters(self) -> list[nn.Parameter]:
        """Density planes and lines."""
        return [*self.density_planes, *self.density_lines]

    def appearance_grid_parameters(self) -> list[nn.Parameter]:
        """Appearance planes and lines."""
        return [*self.appearance_planes, *self.appearance_lines]

    def network_parameters(self) -> list[nn.Parameter]:
        """Basis matrix and shading MLP."""
        return [*self.basis_mat.parameters(), *self.mlp.parameters()]

    def freeze_density(self) -> None:
        """Stop gradients into the density (relighting: paper §3.3, "we freeze the density field")."""
        for p in self.density_parameters():
            p.requires_grad_(False)

    # ------------------------------------------------------------------ regularisers
    def density_l1(self) -> Tensor:
        """TensoRF's `density_L1`: sum of mean |M| + mean |v| over the density factors (NaN-guarded)."""
        total = sum(
            (p.abs().mean() + l.abs().mean() for p, l in
             zip(self.density_planes, self.density_lines, strict=True)),
            self.aabb.new_zeros(()),
        )  # fmt: skip
        return finite_or_zero(total, "density_l1")

    def tv_density(self) -> Tensor:
        """TensoRF's `TV_loss_density`: 1e-2 x TV of each density plane (NaN-guarded)."""
        total = sum((_tv_2d(p) * 1e-2 for p in self.density_planes), self.aabb.new_zeros(()))
        return finite_or_zero(total, "tv_density")

    def tv_appearance(self) -> Tensor:
        """TensoRF's `TV_loss_app`: 1e-2 x TV of each appearance plane (NaN-guarded)."""
        total = sum((_tv_2d(p) * 1e-2 for p in self.appearance_planes), self.aabb.new_zeros(()))
        return finite_or_zero(total, "tv_appearance")

    # ------------------------------------------------------------------ alpha mask
    def sample_alpha_mask(self, xyz_world: Float[Tensor, "N 3"]) -> Float[Tensor, " N"]:
        """Occupancy in [0, 1] of the alpha mask at world points (1 everywhere without a mask)."""
        if self.alpha_volume is None or self.alpha_aabb is None:
            return xyz_world.new_ones(xyz_world.shape[0])
        size = self.alpha_aabb[1] - self.alpha_aabb[0]
        norm = (xyz_world - self.alpha_aabb[0]) * (2.0 / size) - 1.0
        vol = self.alpha_volume.to(xyz_world.dtype)
        return F.grid_sample(vol, norm.view(1, -1, 1, 1, 3), align_corners=True).view(-1)

    @torch.no_grad()
    def dense_alpha(self, grid_size: GridSize | None = None, chunk: int = 65536) -> Tensor:
        """Opacity `1 - exp(-sigma * step)` at every grid point, `[X, Y, Z]` (TensoRF's `compute_alpha`).

        As in TensoRF, without `distance_scale`: the render uses sigma * delta * 25, so the mask keeps
        points whose one-step render alpha reaches 25 x `alpha_mask_threshold`. The threshold (1e-4) is
        calibrated for this form; with the factor it keeps the untrained field's whole box.
        """
        gs = grid_size or self.grid_size
        axes = [torch.linspace(0, 1, n, device=self.aabb.device) for n in gs]
        t = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)  # [X, Y, Z, 3]
        xyz = (self.aabb[0] * (1 - t) + self.aabb[1] * t).reshape(-1, 3)
        alpha = torch.empty(xyz.shape[0], device=xyz.device)
        scale = self.step_size
        for s in range(0, xyz.shape[0], chunk):
            pts = xyz[s : s + chunk]
            keep = self.sample_alpha_mask(pts) > 0
            sigma = torch.zeros(pts.shape[0], device=pts.device)
            if bool(keep.any()):
                sigma[keep] = self.density(pts[keep])
            alpha[s : s + chunk] = 1.0 - torch.exp(-sigma * scale)
        return alpha.view(*gs)

    @torch.no_grad()
    def update_alpha_mask(self, grid_size: GridSize | None = None) -> AlphaMaskInfo:
        """Rebuild the alpha mask (empty-space skipping) from the current density.

        Opacity on the grid, 3x3x3 max-pool (a safety margin of one voxel), threshold
        `alpha_mask_threshold`. An all-empty result is NOT installed (it would hide every sample from
        the optimiser forever); an `EmptyAlphaMaskWarning` is issued instead.

        Returns:
            `AlphaMaskInfo` with the occupied box (the shrink target) when anything is occupied.
        """
        gs = grid_size or self.grid_size
        alpha = self.dense_alpha(gs)  # [X, Y, Z]
        vol = alpha.permute(2, 1, 0).contiguous()[None, None]  # [1, 1, Z, Y, X] for grid_sample
        vol = F.max_pool3d(vol, kernel_size=3, padding=1, stride=1)
        occupied = (vol >= self.config.alpha_mask_threshold).float()
        frac = float(occupied.mean())
        if frac == 0.0:
            warnings.warn(
                "The alpha mask is empty: no grid point has opacity >= "
                f"{self.config.alpha_mask_threshold:g}. Keeping the previous mask and box. If the "
                "scene has an object, the density has not grown yet: move the first "
                "`alpha_mask_at` iteration later or raise the learning rate.",
                EmptyAlphaMaskWarning,
                stacklevel=2,
            )
            return AlphaMaskInfo(occupied_fraction=0.0, occupied_aabb=None, empty=True)
        self.alpha_volume = occupied
        self.alpha_aabb = self.aabb.clone()
        axes = [torch.linspace(0, 1, n, device=self.aabb.device) for n in gs]
        t = torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)  # [X, Y, Z, 3]
        xyz = self.aabb[0] * (1 - t) + self.aabb[1] * t
        pts = xyz[occupied[0, 0].permute(2, 1, 0) > 0.5]
        box = torch.stack([pts.amin(dim=0), pts.amax(dim=0)])
        return AlphaMaskInfo(occupied_fraction=frac, occupied_aabb=box, empty=False)

    # ------------------------------------------------------------------ resizing
    @torch.no_grad()
    def upsample(self, grid_size: GridSize) -> None:
        """Resample every factor to `grid_size` (bilinear, align_corners), keeping the box.

        Parameters are replaced: rebuild the optimiser afterwards.
        """
        gs = _check_grid("grid_size", grid_size)
        for planes, lines in (
            (self.density_planes, self.density_lines),
            (self.appearance_planes, self.appearance_lines),
        ):
            for i, (a, b) in enumerate(MAT_MODE):
                c = VEC_MODE[i]
                planes[i] = nn.Parameter(
                    F.interpolate(
                        planes[i].data, size=(gs[b], gs[a]), mode="bilinear", align_corners=True
                    ),
                    requires_grad=planes[i].requires_grad,
                )
                lines[i] = nn.Parameter(
                    F.interpolate(
                        lines[i].data, size=(gs[c], 1), mode="bilinear", align_corners=True
                    ),
                    requires_grad=lines[i].requires_grad,
                )
        self.grid_size = gs

    @torch.no_grad()
    def shrink(self, new_aabb: Float[Tensor, "2 3"]) -> None:
        """Crop every factor to the grid points covering `new_aabb` (TensoRF's `shrink`).

        The box snaps outwards to grid points, so the voxel pitch is unchanged and no value is
        resampled. Parameters are replaced: rebuild the optimiser afterwards.
        """
        if tuple(new_aabb.shape) != (2, 3):
            raise ShapeError("new_aabb", tuple(new_aabb.shape), "[2, 3]")
        n = torch.tensor(self.grid_size, device=self.aabb.device)
        lo = torch.floor((new_aabb[0] - self.aabb[0]) / self.units + 1e-4).long().clamp(0)
        hi = torch.ceil((new_aabb[1] - self.aabb[0]) / self.units - 1e-4).long() + 1
        hi = torch.minimum(hi, n)
        # at least 2 grid points per axis, so every voxel pitch stays defined
        hi = torch.maximum(hi, torch.minimum(lo + 2, n))
        lo = torch.minimum(lo, hi - 2)
        for planes, lines in (
            (self.density_planes, self.density_lines),
            (self.appearance_planes, self.appearance_lines),
        ):
            for i, (a, b) in enumerate(MAT_MODE):
                c = VEC_MODE[i]
                planes[i] = nn.Parameter(
                    planes[i].data[..., lo[b] : hi[b], lo[a] : hi[a]].contiguous(),
                    requires_grad=planes[i].requires_grad,
                )
                lines[i] = nn.Parameter(
                    lines[i].data[..., lo[c] : hi[c], :].contiguous(),
                    requires_grad=lines[i].requires_grad,
                )
        units = self.units.clone()
        start = self.aabb[0].clone()
        self.aabb.copy_(torch.stack([start + lo * units, start + (hi - 1) * units]))
        self.grid_size = (int(hi[0] - lo[0]), int(hi[1] - lo[1]), int(hi[2] - lo[2]))

    def grid_memory_bytes(self) -> int:
        """Bytes held by the factor grids (what the grid size costs)."""
        return sum(
            p.numel() * p.element_size()
            for p in (*self.density_parameters(), *self.appearance_grid_parameters())
        )


def voxels_to_grid(num_voxels: int, aabb: Float[Tensor, "2 3"]) -> GridSize:
    """Grid points per axis with about `num_voxels` cubic voxels over the box (TensoRF `N_to_reso`)."""
    size = (aabb[1] - aabb[0]).double()
    voxel = (float(size.prod()) / num_voxels) ** (1.0 / 3.0)
    res = (size / voxel).long().clamp(min=2).tolist()
    return (int(res[0]), int(res[1]), int(res[2]))


def _check_grid(name: str, grid_size: GridSize) -> GridSize:
    gs = tuple(int(g) for g in grid_size)
    if len(gs) != 3 or min(gs) < 2:
        raise ConfigError(f"`{name}` is {grid_size!r}; expected three sizes >= 2.")
    return (gs[0], gs[1], gs[2])


def _init_vm(
    ranks: tuple[int, int, int], gs: GridSize, scale: float, generator: torch.Generator | None
) -> tuple[nn.ParameterList, nn.ParameterList]:
    planes, lines = [], []
    for i, (a, b) in enumerate(MAT_MODE):
        c = VEC_MODE[i]
        planes.append(
            nn.Parameter(scale * torch.randn((1, ranks[i], gs[b], gs[a]), generator=generator))
        )
        lines.append(
            nn.Parameter(scale * torch.randn((1, ranks[i], gs[c], 1), generator=generator))
        )
    return nn.ParameterList(planes), nn.ParameterList(lines)


def log_spaced_voxels(initial: int, final: int, steps: int) -> list[int]:
    """Voxel counts of the upsampling schedule: `steps` values log-spaced after `initial` up to `final`.

    Example:
        >>> log_spaced_voxels(8, 64, 3)
        [16, 32, 64]
    """
    if steps <= 0:
        return []
    a, b = math.log(initial), math.log(final)
    return [round(math.exp(a + (b - a) * (k + 1) / steps)) for k in range(steps)]
