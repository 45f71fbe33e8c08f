"""Render a field at test poses and score it against ground truth under the TARGET lighting.

The authors' 3D metrics compare against the wrong images (official implementation §6, §8); here the
reference is the test split rendered under the target lighting (gaffer-data's `lit/{VVV}_{LLL}.png` for
the target `LLL`). Scores come from `gaffer_diffusion.metrics.evaluate_images`: PSNR, SSIM and a labelled
perceptual distance, raw and channel-aligned (means over the whole image and over the object mask).
"""

import warnings
from pathlib import Path
from typing import Literal

import numpy as np
import torch
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from gaffer_diffusion.metrics import MetricsReport, PerceptualMetric, evaluate_images
from gaffer_envmap.atomic import atomic_files
from gaffer_envmap.writers import write_png
from gaffer_nerf.cameras import Cameras
from gaffer_nerf.data.transforms import ViewSet
from gaffer_nerf.errors import ShapeError
from gaffer_nerf.fields.tensorf import TensoRFVM
from gaffer_nerf.rendering import render_rays_chunked


class EmptyMaskWarning(UserWarning):
    """Some ground-truth alpha masks are empty, so their mask-aligned scores use the whole image."""


@torch.no_grad()
def render_views(
    field: TensoRFVM, cameras: Cameras, *, chunk: int = 8192
) -> Float[Tensor, "V 3 H W"]:
    """Full images at every camera, `[V, 3, H, W]` in [0, 1] on the CPU (channels first for metrics)."""
    device = field.aabb.device
    out = []
    for v in range(cameras.num_views):
        rays = cameras.rays([v]).to(device)
        rgb = render_rays_chunked(field, rays, chunk=chunk).rgb.cpu()
        out.append(rgb.T.reshape(3, cameras.height, cameras.width))
    return torch.stack(out)


def evaluate_field(
    field: TensoRFVM,
    ground_truth: ViewSet,
    *,
    perceptual: PerceptualMetric | Literal["auto"] | None = "auto",
) -> tuple[MetricsReport, Float[Tensor, "V 3 H W"]]:
    """Render `ground_truth`'s cameras and score the renders against its images.

    Args:
        field: the (relit) field.
        ground_truth: test views under the target lighting (composited over white, like renders).
        perceptual: as `gaffer_diffusion.metrics.evaluate_images`.

    Returns:
        The `MetricsReport` (the masked alignment uses the ground-truth alpha when present) and the
        renders `[V, 3, H, W]`.
    """
    pred = render_views(field, ground_truth.cameras)
    return score_images(pred, ground_truth, perceptual=perceptual), pred


def score_images(
    pred: Float[Tensor, "V 3 H W"],
    ground_truth: ViewSet,
    *,
    perceptual: PerceptualMetric | Literal["auto"] | None = "auto",
) -> MetricsReport:
    """Score predictions (e.g. read back from PNGs) against a `ViewSet` of the same cameras.

    A view whose ground-truth alpha is empty (no object in frame) has no masked alignment: the
    scale fitted over zero pixels is 0 and would score a black image. Such views are aligned over the
    whole image instead; when every mask is empty the masked variant is left out of the report.
    Either case warns (`EmptyMaskWarning`) with the view names.

    Raises:
        ShapeError: when the shapes differ.
    """
    gt = ground_truth.rgb_srgb.permute(0, 3, 1, 2).contiguous()
    if tuple(pred.shape) != tuple(gt.shape):
        raise ShapeError("pred", tuple(pred.shape), f"{tuple(gt.shape)} (the ground truth's)")
    mask = None if ground_truth.alpha is None else ground_truth.alpha[:, None].float()
    if mask is not None:
        empty = (mask.flatten(1).sum(dim=1) <= 0).nonzero().flatten().tolist()
        if len(empty) == mask.shape[0]:
            warnings.warn(
                "Every ground-truth alpha mask is empty (no object in view); the mask-aligned "
                "scores are left out (raw and whole-image-aligned only).",
                EmptyMaskWarning,
                stacklevel=2,
            )
            mask = None
        elif empty:
            names = [ground_truth.names[i] for i in empty]
            warnings.warn(
                f"Views {names} have an empty ground-truth alpha mask; their mask-aligned scores "
                "use the whole image.",
                EmptyMaskWarning,
                stacklevel=2,
            )
            mask = mask.clone()
            mask[empty] = 1.0
    return evaluate_images(
        pred.float().clamp(0, 1),
        gt.float(),
        mask=mask,
        names=list(ground_truth.names),
        perceptual=perceptual,
    )


def write_images(
    images: Float[Tensor, "V 3 H W"], folder: str | Path, names: list[str]
) -> list[Path]:
    """Write `[V, 3, H, W]` images in [0, 1] as 8-bit PNGs `folder/<name>.png`, all or none.

    Quantised by `gaffer_envmap.writers` (nearest level, ties to even). gaffer-nerf used to round half
    up: a value exactly halfway up to an odd level (x * 255 = 2k + 0.5) is now saved one level lower.

    The set is staged in a hidden folder inside `folder` and renamed into place at the end
    (`gaffer_envmap.atomic.atomic_files`), so an interrupted run (even kill -9) leaves no part of a set
    under the final names and an earlier run's files as they were.
    """
    folder = Path(folder)
    with atomic_files(folder) as stage:
        for img, name in zip(images, names, strict=True):
            write_png(stage / f"{name}.png", img.permute(1, 2, 0))
    return [folder / f"{name}.png" for name in names]


def read_images(paths: list[Path]) -> Float[Tensor, "V 3 H W"]:
    """8-bit RGB PNGs as `[V, 3, H, W]` in [0, 1]."""
    arrs = []
    for p in paths:
        with Image.open(p) as im:
            arrs.append(np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0)
    return torch.from_numpy(np.stack(arrs)).permute(0, 3, 1, 2).contiguous()
