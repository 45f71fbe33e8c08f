"""Grid resolution from what the cameras can resolve ("model no more than the scene needs").

The paper fixes the final grid at 300^3 voxels whatever the capture. A pinhole camera at depth z with
focal f (pixels) sees one pixel as a patch of width z / f; detail finer than the finest camera's
footprint cannot be constrained by any image, so voxels much smaller than it only cost memory and time.
With `GridSizingConfig(mode="footprint")` the final voxel size is

    voxel = min_v (depth_v / fx_v) / oversample

(depth of the box centre in camera v), and the final resolution per axis is extent / voxel, clamped to
[min_resolution, max_resolution]. For the authors' setup (256 px, focal 280 px, cameras 1.5-2.2 from an
object of side 1) that is about 0.0054-0.0079 world units, i.e. ~130-190 voxels across the object
instead of the ~300 the fixed 300^3 grid reaches after the box shrinks to the object.

The iteration budget caps it as well (`GridSizingConfig.rays_per_cell`): a fit of I iterations of B
rays can train at most R = sqrt(I B / rays_per_cell) cells per factor-plane axis. The default (768)
puts a 300-iteration CPU fit at 20^3, the peak of the fixed-grid curve for that budget, rather than the
45^3 its pixels could resolve (which it cannot train in that time: 2.3 dB lower and twice the time in
`benchmarks/bench_nerf_sizing.py`); the paper's schedule allows more than its own 300^3 cap.
"""

import math
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_nerf.cameras import Cameras
from gaffer_nerf.configs import FitConfig, GridSizingConfig
from gaffer_nerf.errors import CameraError
from gaffer_nerf.fields.tensorf import GridSize, voxels_to_grid


@dataclass(frozen=True, kw_only=True)
class GridSizing:
    """The resolution decision, with the numbers behind it.

    Attributes:
        mode: "fixed" or "footprint".
        footprint: finest pixel footprint at the box centre over all cameras (world units).
        voxel_size: target voxel edge ("footprint" mode), or None ("fixed").
        oversample: voxels per footprint.
    """

    mode: str
    footprint: float
    voxel_size: float | None
    oversample: float

    def final_grid(self, aabb: Float[Tensor, "2 3"], config: FitConfig) -> GridSize:
        """Final grid points per axis for the (possibly shrunk) box `aabb`."""
        if self.voxel_size is None:
            return voxels_to_grid(config.final_voxels, aabb)
        lim = config.sizing
        extent = (aabb[1] - aabb[0]).tolist()
        res = [math.ceil(e / self.voxel_size) + 1 for e in extent]
        side = budget_side(config)
        if side is not None:  # no more voxels than the iteration budget can train
            cap = voxels_to_grid(max(round(side**3), 1), aabb)
            res = [min(r, c) for r, c in zip(res, cap, strict=True)]
        res = [min(lim.max_resolution, max(lim.min_resolution, r)) for r in res]
        return (res[0], res[1], res[2])

    def final_voxels(self, aabb: Float[Tensor, "2 3"], config: FitConfig) -> int:
        """Voxel count of `final_grid`."""
        g = self.final_grid(aabb, config)
        return g[0] * g[1] * g[2]


def budget_side(config: FitConfig) -> float | None:
    """R = sqrt(iterations x batch_rays / rays_per_cell): the grid side the fit's budget can train.

    None when `config.sizing.rays_per_cell` is None. Early stopping may end the fit sooner; the
    budget is the iterations it may run.

    Example:
        >>> from gaffer_nerf.configs import fit_preset
        >>> round(budget_side(fit_preset("paper")))  # above the paper's 300^3 cap
        400
        >>> round(budget_side(fit_preset("tiny")), 1)  # 300 iterations of 1024 rays
        20.0
    """
    per_cell = config.sizing.rays_per_cell
    if per_cell is None:
        return None
    return math.sqrt(config.iterations * config.batch_rays / per_cell)


def choose_grid_sizing(
    cameras: Cameras, aabb: Float[Tensor, "2 3"], config: GridSizingConfig
) -> GridSizing:
    """Decide the voxel size from the cameras' pixel footprint at the centre of `aabb`.

    Raises:
        CameraError: when no camera has the box centre in front of it.

    Example:
        >>> import torch
        >>> from gaffer_nerf.cameras import Cameras
        >>> c2w = torch.eye(4)[None].clone(); c2w[0, 2, 3] = -2.0  # 2 units in front of the origin
        >>> cams = Cameras(c2w_opencv=c2w, focal_px=torch.tensor([[200.0, 200.0]]),
        ...                principal_px=torch.tensor([[64.0, 64.0]]), width=128, height=128)
        >>> s = choose_grid_sizing(cams, torch.tensor([[-1.0] * 3, [1.0] * 3]),
        ...                        GridSizingConfig(mode="footprint"))
        >>> round(s.footprint, 4), round(s.voxel_size, 4)
        (0.01, 0.01)
    """
    center = aabb.mean(dim=0)
    fp = cameras.pixel_footprint(center)
    finite = fp[torch.isfinite(fp)]
    if finite.numel() == 0:
        raise CameraError(
            "No camera has the scene box centre in front of it; check the pose convention "
            "(OpenGL/Blender files look along -z) and the box (`SceneBoxConfig`)."
        )
    footprint = float(finite.min())
    if config.mode == "fixed":
        return GridSizing(mode="fixed", footprint=footprint, voxel_size=None, oversample=1.0)
    return GridSizing(
        mode="footprint",
        footprint=footprint,
        voxel_size=footprint / config.oversample,
        oversample=config.oversample,
    )
