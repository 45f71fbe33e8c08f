"""Training and scoring the normal estimator (`gaffer_diffusion.geometry.estimator`) on gaffer-data renders.

Every gaffer-data view has a normal pass (`area/normal`, world frame, Blender z up) beside its lit
renders; rotated by the view's world-to-camera matrix it is the camera-frame truth the hints need. The
input of each training sample is one of the view's renders (any of its env-map lightings, or the
area-light render), framed as every gaffer-tiny path frames a photo (`object_square`, 75%), so the
estimator learns shape from shading under many lights. Loss: 1 - cos over the mask.

`angular_errors` scores it (and the silhouette dome, `gaffer_diffusion.hints.silhouette_normals`,
beside it) on held-out renders: the mean angle in degrees over the object's pixels.
"""

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float, UInt8
from torch import Tensor

from gaffer_data import read_object
from gaffer_data.dataset import RenderedObject
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.geometry.estimator import (
    NormalEstimator,
    NormalEstimatorConfig,
    estimate_normals,
)
from gaffer_diffusion.hints import silhouette_normals
from gaffer_diffusion.images import crop_square, load_rgba_on_white, read_alpha
from gaffer_diffusion.preprocess import object_square
from gaffer_diffusion.training.objects import dataset_object_ids
from gaffer_envmap.io_exr import read_exr_array
from gaffer_envmap.writers import quantize

logger = logging.getLogger(__name__)

__all__ = [
    "AngularErrors",
    "GeometryViews",
    "NormalTrainConfig",
    "angular_errors",
    "concat_views",
    "load_geometry_views",
    "mean_angular_error_deg",
    "train_normal_estimator",
    "view_normals_cam",
]


@dataclass(frozen=True, kw_only=True)
class GeometryViews:
    """Every view of some renders, framed and resized, in memory.

    Attributes:
        images: `[V, L, 3, S, S]` uint8 display sRGB on white (L renders per view: lit + area).
        masks: `[V, 1, S, S]` float32 alpha in [0, 1].
        normals_cam: `[V, 3, S, S]` float32 unit camera-frame normals (x right, y up, z to the camera),
            zero where the pass has no surface.
        object_ids: the object of each view.
    """

    images: UInt8[Tensor, "V L 3 S S"]
    masks: Float[Tensor, "V 1 S S"]
    normals_cam: Float[Tensor, "V 3 S S"]
    object_ids: tuple[str, ...]


def view_normals_cam(
    obj: RenderedObject, rel: str, w2c: np.ndarray, box: tuple[int, int, int] | None, size: int
) -> Tensor:
    """`[3, size, size]` camera-frame normals of a view's normal pass (`box`: the crop, None: whole)."""
    n_world = read_exr_array(obj.path(rel))[..., :3].astype(np.float32)
    if box is not None:
        n_world = crop_square(n_world, box, 0.0)
    t = torch.from_numpy(np.ascontiguousarray(n_world)).permute(2, 0, 1)[None]
    t = F.interpolate(t, size=(size, size), mode="bilinear", antialias=True)[0]
    # Blender camera axes are x right, y up, z backward (toward the viewer): the hints' frame
    n_cam = torch.einsum("ij,jhw->ihw", torch.from_numpy(w2c[:3, :3].astype(np.float32)), t)
    norm = n_cam.norm(dim=0, keepdim=True)
    return torch.where(norm > 0.5, n_cam / norm.clamp_min(1e-6), torch.zeros_like(n_cam))


def load_geometry_views(
    root: str | Path, *, size: int = 128, object_fraction: float = 0.75
) -> GeometryViews:
    """Read every view of a gaffer-data render folder that has a normal pass.

    Raises:
        ConfigError: the folder has no view with a normal pass (rendered with `--no-area-light`).
    """
    images, masks, normals, ids = [], [], [], []
    for oid in dataset_object_ids(root):
        obj = read_object(Path(root) / "objects" / oid)
        poses = obj.poses()
        for view in obj.views:
            if view.area is None or view.alpha is None:
                continue
            alpha_path = obj.path(view.alpha)
            box = object_square(read_alpha(alpha_path), object_fraction)
            pngs = [obj.path(li.png) for li in view.lit] + [obj.path(view.area.png)]
            rgbs = []
            alpha = None
            for png in pngs:
                rgb, alpha = load_rgba_on_white(png, size, alpha_path, box)
                rgbs.append(torch.from_numpy(quantize(rgb)))
            w2c = np.asarray(poses.w2c_blender[view.index], dtype=np.float64)
            images.append(torch.stack(rgbs))
            masks.append(alpha)
            normals.append(view_normals_cam(obj, view.area.normal, w2c, box, size))
            ids.append(oid)
    if not images:
        raise ConfigError(
            f"`{root}` holds no view with a normal pass; render it without `--no-area-light`."
        )
    n_lit = min(int(im.shape[0]) for im in images)
    return GeometryViews(
        images=torch.stack([im[:n_lit] for im in images]),
        masks=torch.stack(masks).float(),
        normals_cam=torch.stack(normals),
        object_ids=tuple(ids),
    )


def concat_views(parts: Sequence[GeometryViews]) -> GeometryViews:
    """The views of several render folders pooled in one set (same size). Each view keeps as many
    renders as the folder with the fewest per view has (e.g. 4 lightings + the area light when one
    folder was rendered with `--lightings 4` and another with 8): `_batch` draws one per view.

    Raises:
        ConfigError: no parts, or parts of different sizes.
    """
    if not parts:
        raise ConfigError("no training views: pass at least one render folder.")
    sizes = {tuple(p.images.shape[-2:]) for p in parts}
    if len(sizes) > 1:
        raise ConfigError(f"the render folders' views differ in size ({sorted(sizes)}).")
    if len(parts) == 1:
        return parts[0]
    n_lit = min(int(p.images.shape[1]) for p in parts)
    return GeometryViews(
        images=torch.cat([p.images[:, :n_lit] for p in parts]),
        masks=torch.cat([p.masks for p in parts]),
        normals_cam=torch.cat([p.normals_cam for p in parts]),
        object_ids=tuple(oid for p in parts for oid in p.object_ids),
    )


@dataclass(frozen=True, kw_only=True)
class NormalTrainConfig:
    """How the estimator is trained (defaults: the shipped gaffer-normals recipe).

    Attributes:
        estimator: its shapes.
        max_seconds: wall-clock budget; training stops at the first step past it.
        max_steps: step budget.
        batch_size: views per step.
        lr: AdamW learning rate (cosine decay to 10% over `max_steps`).
        seed: data order, augmentation and initialisation.
        threads: torch CPU threads (0: leave torch's default).
    """

    estimator: NormalEstimatorConfig = field(default_factory=NormalEstimatorConfig)
    max_seconds: float = 900.0
    max_steps: int = 4000
    batch_size: int = 16
    lr: float = 2e-3
    seed: int = 0
    threads: int = 0

    def __post_init__(self) -> None:
        for name in ("max_seconds", "max_steps", "batch_size", "lr"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"`{name}` is {getattr(self, name)}; expected a positive value.")


def _cosine_loss(
    pred: Float[Tensor, "B 3 H W"], truth: Float[Tensor, "B 3 H W"], mask: Float[Tensor, "B 1 H W"]
) -> Tensor:
    valid = ((mask > 0.5) & (truth.norm(dim=1, keepdim=True) > 0.5)).float()
    cos = (pred * truth).sum(dim=1, keepdim=True)
    return ((1.0 - cos) * valid).sum() / valid.sum().clamp_min(1.0)


def _batch(
    views: GeometryViews, idx: Tensor, gen: torch.Generator
) -> tuple[Tensor, Tensor, Tensor]:
    """Images (a random render per view, random exposure), masks, normals; mirrored at random."""
    b = idx.numel()
    which = torch.randint(0, views.images.shape[1], (b,), generator=gen)
    img = views.images[idx, which].float() / 255.0
    mask = views.masks[idx]
    nrm = views.normals_cam[idx].clone()
    # exposure +-1 stop on the object only (approximately, in display space): shape, not brightness
    gain = torch.exp2(torch.empty(b, 1, 1, 1).uniform_(-1.0, 1.0, generator=gen)) ** (1 / 2.2)
    img = (img * gain).clamp(0, 1) * mask + img * (1 - mask)
    flip = torch.rand(b, generator=gen) < 0.5
    img[flip] = img[flip].flip(-1)
    mask = torch.where(flip.view(b, 1, 1, 1), mask.flip(-1), mask)
    nrm[flip] = nrm[flip].flip(-1) * torch.tensor([-1.0, 1.0, 1.0]).view(1, 3, 1, 1)
    return img, mask, nrm


def train_normal_estimator(
    train: GeometryViews, config: NormalTrainConfig, *, init: NormalEstimator | None = None
) -> tuple[NormalEstimator, dict[str, float]]:
    """Train on `train` from scratch, or on from `init` (a copy is trained; its shapes must be
    `config.estimator`); returns the estimator (eval mode) and `{steps, seconds, loss}`.

    Raises:
        ConfigError: `init`'s shapes differ from `config.estimator`.
    """
    if init is not None and init.config != config.estimator:
        raise ConfigError(
            f"the estimator to continue from has shapes {init.config}, the config asks for "
            f"{config.estimator}; pass the same shapes."
        )
    # the caller's thread count comes back afterwards: a forward pass's float sums depend on it,
    # so leaving it changed would make the caller's own results differ after training
    threads_before = torch.get_num_threads()
    if config.threads > 0:
        torch.set_num_threads(config.threads)
    try:
        return _train(train, config, init)
    finally:
        torch.set_num_threads(threads_before)


def _train(
    train: GeometryViews, config: NormalTrainConfig, init: NormalEstimator | None
) -> tuple[NormalEstimator, dict[str, float]]:
    torch.manual_seed(config.seed)
    gen = torch.Generator().manual_seed(config.seed)
    est = NormalEstimator(config.estimator)
    if init is not None:
        est.load_state_dict(init.state_dict())
    est = est.train()
    opt = torch.optim.AdamW(est.parameters(), lr=config.lr, weight_decay=1e-4)

    def lr_at(step: int) -> float:
        warm = min(1.0, (step + 1) / 50)
        decay = 0.1 + 0.45 * (1 + math.cos(math.pi * min(step / config.max_steps, 1.0)))
        return config.lr * warm * decay

    start = time.perf_counter()
    step, ema = 0, float("nan")
    n = train.images.shape[0]
    order = torch.randperm(n, generator=gen)
    pos = 0
    while step < config.max_steps and time.perf_counter() - start < config.max_seconds:
        if pos + config.batch_size > n:
            order, pos = torch.randperm(n, generator=gen), 0
        idx = order[pos : pos + config.batch_size]
        pos += config.batch_size
        img, mask, nrm = _batch(train, idx, gen)
        for g in opt.param_groups:
            g["lr"] = lr_at(step)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            pred = est(img, mask)
        loss = _cosine_loss(pred.float(), nrm, mask)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(est.parameters(), 1.0)
        opt.step()
        value = loss.item()
        ema = value if math.isnan(ema) else 0.98 * ema + 0.02 * value
        step += 1
        if step % 50 == 0:
            logger.info("step %d  loss %.4f  %.0f s", step, ema, time.perf_counter() - start)
    seconds = time.perf_counter() - start
    return est.eval(), {"steps": float(step), "seconds": seconds, "loss": ema}


@dataclass(frozen=True, kw_only=True)
class AngularErrors:
    """Mean angular error in degrees over the object's pixels, per method, on one set of views."""

    estimated_deg: float
    silhouette_dome_deg: float
    views: int


def mean_angular_error_deg(pred: Tensor, truth: Tensor, mask: Tensor) -> float:
    """Mean angle in degrees between `pred` and `truth` normals over the mask's pixels that have a
    true normal (the pass is zero where no surface was hit)."""
    valid = (mask > 0.5) & (truth.norm(dim=1, keepdim=True) > 0.5)
    cos = (pred * truth).sum(dim=1, keepdim=True).clamp(-1.0, 1.0)
    return float(torch.rad2deg(torch.acos(cos))[valid].mean())


@torch.no_grad()
def angular_errors(est: NormalEstimator, views: GeometryViews, *, batch: int = 32) -> AngularErrors:
    """Score `est` (with its mirror average, as the hints use it) and the silhouette dome on `views`,
    each view's first render as the input."""
    preds, domes = [], []
    for i in range(0, views.images.shape[0], batch):
        img = views.images[i : i + batch, 0].float() / 255.0
        mask = views.masks[i : i + batch]
        preds.append(estimate_normals(est, img, mask))
        domes.append(silhouette_normals(mask))
    truth, mask = views.normals_cam, views.masks
    return AngularErrors(
        estimated_deg=mean_angular_error_deg(torch.cat(preds), truth, mask),
        silhouette_dome_deg=mean_angular_error_deg(torch.cat(domes), truth, mask),
        views=int(truth.shape[0]),
    )
