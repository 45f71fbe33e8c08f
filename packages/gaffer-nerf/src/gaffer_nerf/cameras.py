"""Pinhole cameras that carry their convention, rays, and the pixel footprint used to size the grid.

Frames: the world is Blender's (z up), as every gaffer artifact. Camera-to-world matrices are OpenCV
(x right, y down, the camera looks along +z), `c2w_opencv`; NeRF-Synthetic / Blender files store OpenGL
(y up, looks along -z) and are converted at the reader with `c2w_opencv = c2w_blender @ diag(1, -1, -1, 1)`.
Relighting needs Blender world-to-camera matrices (`w2c_blender`), derived here.
"""

from dataclasses import dataclass
from typing import TYPE_CHECKING

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor

from gaffer_nerf.errors import CameraError, ShapeError

if TYPE_CHECKING:
    _C2W = Float[Tensor, "V 4 4"]
    _PerView2 = Float[Tensor, "V 2"]
else:  # `Cameras.__post_init__` checks these shapes itself (a ShapeError naming the field), so at
    # run time the fields take any tensor and the test-time type hook does not refuse first
    _C2W = _PerView2 = Tensor

_OPENCV_TO_BLENDER = torch.tensor([1.0, -1.0, -1.0])


@dataclass(frozen=True, kw_only=True)
class RayBundle:
    """Rays in world space.

    Attributes:
        origins_world: `[N, 3]` ray origins.
        dirs_world: `[N, 3]` unit directions.
    """

    origins_world: Float[Tensor, "N 3"]
    dirs_world: Float[Tensor, "N 3"]

    def __len__(self) -> int:
        return int(self.origins_world.shape[0])

    def select(self, index: Int[Tensor, " K"] | Bool[Tensor, " N"] | slice) -> "RayBundle":
        """The rays at `index`."""
        return RayBundle(origins_world=self.origins_world[index], dirs_world=self.dirs_world[index])

    def to(self, device: torch.device | str) -> "RayBundle":
        """A copy on `device`."""
        return RayBundle(
            origins_world=self.origins_world.to(device), dirs_world=self.dirs_world.to(device)
        )


@dataclass(frozen=True, kw_only=True)
class Cameras:
    """V pinhole cameras of one image size.

    Attributes:
        c2w_opencv: `[V, 4, 4]` float32 OpenCV camera-to-world matrices (Blender world, z up).
        focal_px: `[V, 2]` focal lengths (fx, fy) in pixels.
        principal_px: `[V, 2]` principal points (cx, cy) in pixels (pixel centres at +0.5).
        width: image width W in pixels.
        height: image height H in pixels.

    Raises:
        CameraError: NaN/Inf poses, a rotation part that is not a rotation, a last row other than
            [0, 0, 0, 1], or non-positive focal lengths (the message names the views).
        ShapeError: wrongly shaped tensors.

    Example:
        >>> import torch
        >>> cams = Cameras(c2w_opencv=torch.eye(4)[None], focal_px=torch.tensor([[50.0, 50.0]]),
        ...                principal_px=torch.tensor([[16.0, 16.0]]), width=32, height=32)
        >>> len(cams.rays()), cams.num_views
        (1024, 1)
    """

    c2w_opencv: _C2W
    focal_px: _PerView2
    principal_px: _PerView2
    width: int
    height: int

    def __post_init__(self) -> None:
        c2w = self.c2w_opencv
        if not isinstance(c2w, Tensor) or c2w.ndim != 3 or tuple(c2w.shape[1:]) != (4, 4):
            raise ShapeError(
                "c2w_opencv",
                tuple(getattr(c2w, "shape", ())),
                "[V, 4, 4]",
                "Stack the 4x4 camera-to-world matrices along a first axis.",
            )
        v = int(c2w.shape[0])
        if v < 1:
            raise CameraError("`c2w_opencv` holds no cameras; pass at least one view.")
        for name in ("focal_px", "principal_px"):
            t = getattr(self, name)
            if not isinstance(t, Tensor) or tuple(t.shape) != (v, 2):
                raise ShapeError(name, tuple(getattr(t, "shape", ())), f"[{v}, 2]")
        if self.width < 1 or self.height < 1:
            raise CameraError(f"`width`={self.width}, `height`={self.height}: both must be >= 1.")
        c2w = c2w.detach().to(torch.float64)
        bad = (~torch.isfinite(c2w).flatten(1).all(dim=1)).nonzero().flatten().tolist()
        if bad:
            raise CameraError(
                f"`c2w_opencv` holds NaN/Inf in views {bad}. Fix or drop those frames in the "
                "transforms file (a failed pose estimate usually shows up this way)."
            )
        last = (c2w[:, 3] - torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)).abs()
        bad = (last.amax(dim=1) > 1e-5).nonzero().flatten().tolist()
        if bad:
            raise CameraError(
                f"`c2w_opencv` views {bad} have a last row other than [0, 0, 0, 1]; pass "
                "camera-to-world rigid transforms."
            )
        rot = c2w[:, :3, :3]
        ortho = (
            (rot @ rot.transpose(1, 2) - torch.eye(3, dtype=torch.float64)).abs().amax(dim=(1, 2))
        )
        det = torch.linalg.det(rot)
        bad = ((ortho > 1e-3) | (det < 0)).nonzero().flatten().tolist()
        if bad:
            raise CameraError(
                f"`c2w_opencv` views {bad} do not hold a rotation (|R R^T - I| up to "
                f"{float(ortho.max()):.2e}, det {det[bad].tolist()}). Remove scale/shear from the "
                "poses, and check the axis convention (OpenGL/Blender files need "
                "`@ diag(1, -1, -1, 1)`; the readers here do that)."
            )
        f = self.focal_px.detach()
        if not bool(torch.isfinite(f).all()) or bool((f <= 0).any()):
            raise CameraError(
                f"`focal_px` must be finite and > 0; got {f.tolist()}. For NeRF-Synthetic files, "
                "fx = 0.5 W / tan(0.5 camera_angle_x)."
            )
        if not bool(torch.isfinite(self.principal_px).all()):
            raise CameraError("`principal_px` holds NaN/Inf.")

    @property
    def num_views(self) -> int:
        """V."""
        return int(self.c2w_opencv.shape[0])

    @property
    def centers_world(self) -> Float[Tensor, "V 3"]:
        """Camera centres in world coordinates."""
        return self.c2w_opencv[:, :3, 3]

    def select(self, index: Int[Tensor, " K"] | list[int] | slice) -> "Cameras":
        """The cameras at `index`."""
        if isinstance(index, list):
            index = torch.as_tensor(index, dtype=torch.long)
        return Cameras(
            c2w_opencv=self.c2w_opencv[index],
            focal_px=self.focal_px[index],
            principal_px=self.principal_px[index],
            width=self.width,
            height=self.height,
        )

    def w2c_blender(self) -> Float[Tensor, "V 3 4"]:
        """Blender world-to-camera `[R | t]` (x right, y up, looks along -z), for lighting encoding."""
        c2w = self.c2w_opencv.to(torch.float64)
        r_cv = c2w[:, :3, :3].transpose(1, 2)  # world -> OpenCV camera
        r_bl = _OPENCV_TO_BLENDER.to(torch.float64)[None, :, None] * r_cv
        t = -(r_bl @ c2w[:, :3, 3:4])
        return torch.cat([r_bl, t], dim=2).float()

    def check_baseline(self, min_baseline: float = 1e-6) -> None:
        """Raise unless the cameras see the scene from more than one place.

        Raises:
            CameraError: when every camera centre coincides (no parallax: no 3D reconstruction).
        """
        c = self.centers_world.to(torch.float64)
        spread = float((c - c.mean(dim=0)).norm(dim=1).max()) if self.num_views > 1 else 0.0
        if spread <= min_baseline:
            raise CameraError(
                f"All {self.num_views} camera centres coincide (spread {spread:.2e}); a radiance "
                "field needs views from different positions. Check that `transform_matrix` holds "
                "camera-to-world poses (not identity or a repeated frame)."
            )

    def rays(self, view_indices: list[int] | None = None) -> RayBundle:
        """Rays through every pixel centre of the chosen views, in view-major, row-major order.

        Args:
            view_indices: views to use; None for all.

        Returns:
            `RayBundle` of `V' * H * W` rays with unit directions.
        """
        views = list(range(self.num_views)) if view_indices is None else list(view_indices)
        ys, xs = torch.meshgrid(
            torch.arange(self.height, dtype=torch.float32) + 0.5,
            torch.arange(self.width, dtype=torch.float32) + 0.5,
            indexing="ij",
        )
        origins, dirs = [], []
        for v in views:
            fx, fy = self.focal_px[v].float().tolist()
            cx, cy = self.principal_px[v].float().tolist()
            # [H, W, 3]  OpenCV camera-frame directions: x right, y down, z forward
            d_cam = torch.stack([(xs - cx) / fx, (ys - cy) / fy, torch.ones_like(xs)], dim=-1)
            d_cam = d_cam / d_cam.norm(dim=-1, keepdim=True)
            c2w = self.c2w_opencv[v].float()
            d_world = d_cam.reshape(-1, 3) @ c2w[:3, :3].T
            dirs.append(d_world)
            origins.append(c2w[:3, 3].expand_as(d_world))
        return RayBundle(origins_world=torch.cat(origins), dirs_world=torch.cat(dirs))

    def pixel_footprint(self, center_world: Float[Tensor, " 3"]) -> Float[Tensor, " V"]:
        """World-space width of one pixel at the depth of `center_world`, per camera.

        footprint = depth / fx, the pinhole's pixel pitch at that depth. Cameras that have the point
        behind them get +inf.
        """
        c2w = self.c2w_opencv.float()
        forward = c2w[:, :3, 2]  # OpenCV +z
        depth = ((center_world.float()[None] - c2w[:, :3, 3]) * forward).sum(dim=1)
        fp = depth / self.focal_px[:, 0].float()
        return torch.where(depth > 0, fp, torch.full_like(fp, float("inf")))
