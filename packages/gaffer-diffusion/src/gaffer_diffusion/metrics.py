"""Image metrics for relighting (paper §4, official implementation §5).

- PSNR per image, 10 log10(1 / MSE) on [0, 1] images, then averaged (the authors' protocol).
- SSIM via torchmetrics (Gaussian window 11, sigma 1.5, data range 1).
- A perceptual distance, always labelled with what it is:
  - "lpips-alex": standard LPIPS v0.1 (AlexNet), only when the user passes a local file with the ImageNet
    AlexNet backbone (torchvision's `alexnet-owt-7be5be79.pth`); heads from torchmetrics.
  - "stlpips-alex": otherwise, shift-tolerant LPIPS from the `stlpips-pytorch` wheel, which ships its
    complete weights (no download). It is NOT standard LPIPS; numbers are not comparable with the paper's.
  - neither available: the perceptual column is reported as unavailable, with the reason.
- Channel alignment (NeRFactor / InvRender): pred'_c = pred_c * mean(gt_c) / mean(pred_c), clipped to
  [0, 1]. The means are taken over the whole image ("aligned-image") or over a mask ("aligned-mask"); the
  paper does not say which, so both are reported and labelled.
- Object metrics, reported first (`MetricsReport.mean_object_raw` / `mean_object_aligned`): what
  relighting changes is the object, and a white background copied from the input dominates full-frame
  scores. PSNR of the MSE over the mask, SSIM as the mask-weighted mean of the SSIM map, and the
  perceptual distance on the object's bounding-box crop (resized to at least 64 px). "Aligned" there
  is the channel alignment with means over the mask. The full-frame scores (the authors' protocol)
  follow, labelled as such.
"""

import importlib.util
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion._json import json_dumps
from gaffer_diffusion._perceptual import LpipsAlex, StLpipsAlex
from gaffer_diffusion._validate import check_image_batch
from gaffer_diffusion.errors import (
    ConfigError,
    MetricUnavailableError,
    MissingDependencyError,
    ShapeError,
)

PerceptualName = Literal["stlpips-alex", "lpips-alex"]

_EPS = 1e-8


def _check_pair(pred: Tensor, gt: Tensor) -> None:
    check_image_batch("pred", pred)
    check_image_batch("gt", gt)
    if pred.shape != gt.shape:
        raise ShapeError("pred", tuple(pred.shape), f"the shape of `gt` {tuple(gt.shape)}")


def psnr(pred: Tensor, gt: Tensor) -> Float[Tensor, " B"]:
    """Per-image PSNR in dB for `[B, 3, H, W]` images in [0, 1] (inf for identical images).

    Raises:
        ShapeError: `pred` and `gt` are not `[B, 3, H, W]` batches of one shape.

    Example:
        >>> import torch
        >>> round(float(psnr(torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.1))[0]), 3)
        20.0
    """
    _check_pair(pred, gt)
    return _psnr(pred, gt)


def _psnr(pred: Float[Tensor, "B 3 H W"], gt: Float[Tensor, "B 3 H W"]) -> Float[Tensor, " B"]:
    """`psnr` once `_check_pair` has checked the shapes (with a ShapeError naming the argument; the
    public signature takes any tensor so that this error, not the test-time type hook's, speaks)."""
    mse = ((pred.double() - gt.double()) ** 2).mean(dim=(1, 2, 3))
    return (10.0 * torch.log10(1.0 / mse)).float()


def _ssim_torchmetrics(pred: Tensor, gt: Tensor, *, full_image: bool) -> object:
    """torchmetrics' SSIM (Gaussian 11, sigma 1.5, data range 1), per image; with `full_image` also the
    SSIM map."""
    try:
        from torchmetrics.functional.image import structural_similarity_index_measure
    except ImportError as exc:
        raise MissingDependencyError(
            'SSIM needs torchmetrics: pip install "gaffer-diffusion[metrics]"'
        ) from exc
    return structural_similarity_index_measure(
        pred.float(),
        gt.float(),
        gaussian_kernel=True,
        sigma=1.5,
        kernel_size=11,
        data_range=1.0,
        reduction="none",
        return_full_image=full_image,
    )


def ssim(pred: Float[Tensor, "B 3 H W"], gt: Float[Tensor, "B 3 H W"]) -> Float[Tensor, " B"]:
    """Per-image SSIM (torchmetrics; Gaussian 11, sigma 1.5, data range 1).

    Raises:
        MissingDependencyError: without torchmetrics (`pip install "gaffer-diffusion[metrics]"`).
    """
    _check_pair(pred, gt)
    return torch.as_tensor(_ssim_torchmetrics(pred, gt, full_image=False)).reshape(-1)


def masked_psnr(
    pred: Float[Tensor, "B 3 H W"], gt: Float[Tensor, "B 3 H W"], mask: Float[Tensor, "B 1 H W"]
) -> Float[Tensor, " B"]:
    """Per-image PSNR in dB of the mask-weighted MSE (inf for an exact match, nan for an empty mask).

    Example:
        >>> import torch
        >>> m = torch.zeros(1, 1, 4, 4); m[..., :2, :] = 1
        >>> gt = torch.zeros(1, 3, 4, 4); pred = gt.clone(); pred[..., :2, :] = 0.1; pred[..., 2:, :] = 0.9
        >>> round(float(masked_psnr(pred, gt, m)[0]), 3)
        20.0
    """
    _check_pair(pred, gt)
    w = mask.double()
    err = ((pred.double() - gt.double()) ** 2 * w).sum(dim=(1, 2, 3))
    mse = err / (3.0 * w.sum(dim=(1, 2, 3)))
    return (10.0 * torch.log10(1.0 / mse)).float()


def masked_ssim(
    pred: Float[Tensor, "B 3 H W"], gt: Float[Tensor, "B 3 H W"], mask: Float[Tensor, "B 1 H W"]
) -> Float[Tensor, " B"]:
    """Per-image mean of the SSIM map (torchmetrics, as `ssim`) weighted by the mask."""
    _check_pair(pred, gt)
    _, full = _ssim_torchmetrics(pred, gt, full_image=True)  # type: ignore[misc]
    full = torch.as_tensor(full)  # [B, 3, H, W] (torchmetrics pads to the input size)
    w = mask.float()
    if full.shape[2:] != w.shape[2:]:
        w = torch.nn.functional.interpolate(w, size=full.shape[2:], mode="nearest")
    return (full * w).sum(dim=(1, 2, 3)) / (3.0 * w.sum(dim=(1, 2, 3))).clamp_min(_EPS)


def object_crop_box(mask: Float[Tensor, "1 H W"]) -> tuple[int, int, int, int]:
    """`(top, left, bottom, right)` of the mask's pixels above 0.5 (the whole image if none)."""
    ys, xs = torch.nonzero(mask[0] > 0.5, as_tuple=True)
    if ys.numel() == 0:
        return 0, 0, int(mask.shape[1]), int(mask.shape[2])
    return int(ys.min()), int(xs.min()), int(ys.max()) + 1, int(xs.max()) + 1


def channel_align(pred: Tensor, gt: Tensor, mask: Tensor | None = None) -> Float[Tensor, "B 3 H W"]:
    """Rescale each channel of `pred` so its mean matches `gt`'s: pred_c * mean(gt_c) / mean(pred_c).

    Args:
        pred: `[B, 3, H, W]` prediction in [0, 1].
        gt: `[B, 3, H, W]` ground truth in [0, 1].
        mask: `[B, 1, H, W]` weights in [0, 1]; the means are taken over it. None: whole image.

    Returns:
        The aligned prediction, clipped to [0, 1].

    Raises:
        ShapeError: `pred`, `gt` or `mask` of the wrong shape (the message names which).
    """
    _check_pair(pred, gt)
    if mask is not None and (
        mask.ndim != 4 or mask.shape[1] != 1 or mask.shape[2:] != pred.shape[2:]
    ):
        raise ShapeError("mask", tuple(mask.shape), f"[B, 1, {pred.shape[2]}, {pred.shape[3]}]")
    return _channel_align(pred, gt, mask)


def _channel_align(
    pred: Float[Tensor, "B 3 H W"],
    gt: Float[Tensor, "B 3 H W"],
    mask: Float[Tensor, "B 1 H W"] | None,
) -> Float[Tensor, "B 3 H W"]:
    """`channel_align` once its shapes are checked (there with a ShapeError naming the argument)."""
    if mask is None:
        w = torch.ones_like(pred[:, :1])
    else:
        w = mask.to(pred.dtype)
    wsum = w.sum(dim=(2, 3)).clamp_min(_EPS)
    mean_pred = (pred * w).sum(dim=(2, 3)) / wsum  # [B, 3]
    mean_gt = (gt * w).sum(dim=(2, 3)) / wsum
    scale = mean_gt / mean_pred.clamp_min(_EPS)
    return (pred * scale[:, :, None, None]).clamp(0.0, 1.0)


@dataclass(frozen=True, kw_only=True)
class PerceptualMetric:
    """A loaded LPIPS-family network with its honest label.

    Attributes:
        name: "lpips-alex" (standard) or "stlpips-alex" (shift-tolerant, not standard LPIPS).
        source: the weights file(s) used.
    """

    name: PerceptualName
    source: str
    network: torch.nn.Module = field(repr=False, compare=False)

    @torch.no_grad()
    def __call__(
        self, pred: Float[Tensor, "B 3 H W"], gt: Float[Tensor, "B 3 H W"]
    ) -> Float[Tensor, " B"]:
        """Per-image distance between images in [0, 1] (lower is better)."""
        _check_pair(pred, gt)
        p = next(self.network.parameters())
        a = (pred * 2 - 1).to(device=p.device, dtype=p.dtype)
        b = (gt * 2 - 1).to(device=p.device, dtype=p.dtype)
        return self.network(a, b).float().cpu()


def _package_dir(name: str) -> Path | None:
    spec = importlib.util.find_spec(name)
    if spec is None or not spec.submodule_search_locations:
        return None
    return Path(next(iter(spec.submodule_search_locations)))


def stlpips_weights_path() -> Path:
    """The shift-tolerant AlexNet weights inside the installed `stlpips-pytorch` wheel.

    Raises:
        MetricUnavailableError: when the wheel or its weights file is missing.
    """
    root = _package_dir("stlpips_pytorch")
    if root is None:
        raise MetricUnavailableError(
            'stlpips-pytorch is not installed: pip install "gaffer-diffusion[metrics]"'
        )
    path = root / "weights" / "vST0.0" / "alex_shift_tolerant.pth"
    if not path.is_file():
        raise MetricUnavailableError(f"stlpips-pytorch is installed but {path} is missing.")
    return path


def load_perceptual(lpips_backbone: str | Path | None = None) -> PerceptualMetric:
    """Load the perceptual metric, offline.

    Args:
        lpips_backbone: a local torchvision AlexNet state dict (`alexnet-owt-7be5be79.pth`). Given:
            standard LPIPS ("lpips-alex", heads from torchmetrics). None: shift-tolerant LPIPS
            ("stlpips-alex") from the stlpips-pytorch wheel.

    Raises:
        MetricUnavailableError: when the weights cannot be found or loaded (the message says why).
    """
    if lpips_backbone is not None:
        backbone = Path(lpips_backbone).expanduser()
        if not backbone.is_file():
            raise MetricUnavailableError(
                f"`lpips_backbone` {backbone} does not exist. It must be torchvision's ImageNet AlexNet "
                "state dict (alexnet-owt-7be5be79.pth), downloaded beforehand."
            )
        tm = _package_dir("torchmetrics")
        heads = tm / "functional" / "image" / "lpips_models" / "alex.pth" if tm else None
        if heads is None or not heads.is_file():
            raise MetricUnavailableError(
                "standard LPIPS needs the linear heads shipped with torchmetrics: "
                'pip install "gaffer-diffusion[metrics]"'
            )
        net = LpipsAlex()
        try:
            net.load_backbone(torch.load(backbone, map_location="cpu", weights_only=True))
            net.load_heads(torch.load(heads, map_location="cpu", weights_only=True))
        except (KeyError, RuntimeError, OSError) as exc:
            raise MetricUnavailableError(
                f"could not load LPIPS AlexNet weights from {backbone} / {heads}: {exc}"
            ) from exc
        return PerceptualMetric(name="lpips-alex", source=f"{backbone} + {heads}", network=net)
    path = stlpips_weights_path()
    net = StLpipsAlex()
    try:
        net.load_state_dict(torch.load(path, map_location="cpu", weights_only=True), strict=True)
    except (RuntimeError, OSError) as exc:
        raise MetricUnavailableError(
            f"could not load shift-tolerant LPIPS from {path}: {exc}"
        ) from exc
    return PerceptualMetric(name="stlpips-alex", source=str(path), network=net)


@dataclass(frozen=True, kw_only=True)
class ImageScores:
    """Scores of one image (or their means). `perceptual` is None when unavailable."""

    psnr: float
    ssim: float
    perceptual: float | None


@dataclass(frozen=True, kw_only=True)
class ItemMetrics:
    """Scores of one prediction, raw and channel-aligned.

    Attributes:
        name: item label (e.g. file name).
        raw: the prediction as is.
        aligned_image: channel-aligned with means over the whole image.
        aligned_mask: channel-aligned with means over the mask, scored over the whole image (None
            without a mask).
        object_raw: the prediction scored over the object mask (module docstring; None without a
            mask).
        object_aligned: channel-aligned over the mask and scored over it (None without a mask).
    """

    name: str
    raw: ImageScores
    aligned_image: ImageScores
    aligned_mask: ImageScores | None
    object_raw: ImageScores | None = None
    object_aligned: ImageScores | None = None


@dataclass(frozen=True, kw_only=True)
class MetricsReport:
    """Per-item and mean scores, with the perceptual metric's label or the reason it is missing."""

    items: tuple[ItemMetrics, ...]
    mean_raw: ImageScores
    mean_aligned_image: ImageScores
    mean_aligned_mask: ImageScores | None
    perceptual_name: PerceptualName | None
    perceptual_unavailable_reason: str | None = None
    mean_object_raw: ImageScores | None = None
    mean_object_aligned: ImageScores | None = None

    def to_json(self) -> str:
        """The report as strict JSON: an infinite PSNR (identical images) is written as null and
        its JSON Pointer listed under `"non_finite"` (`gaffer_diffusion._json`); never `Infinity`."""
        return json_dumps(asdict(self), indent=2)

    def to_markdown(self) -> str:
        """A markdown table of the means, each row labelled."""
        pname = self.perceptual_name or "perceptual (unavailable)"
        rows = [
            f"| variant | PSNR | SSIM | {pname} |",
            "|---|---|---|---|",
        ]
        variants: list[tuple[str, ImageScores]] = []
        if self.mean_object_raw is not None and self.mean_object_aligned is not None:
            variants += [
                ("object mask, raw", self.mean_object_raw),
                ("object mask, aligned", self.mean_object_aligned),
            ]
        variants += [
            ("full frame, raw", self.mean_raw),
            ("full frame, aligned (whole image)", self.mean_aligned_image),
        ]
        if self.mean_aligned_mask is not None:
            variants.append(("full frame, aligned (mask means)", self.mean_aligned_mask))
        for label, s in variants:
            p = "n/a" if s.perceptual is None else f"{s.perceptual:.4f}"
            rows.append(f"| {label} | {s.psnr:.3f} | {s.ssim:.4f} | {p} |")
        if self.perceptual_unavailable_reason:
            rows.append(f"\nPerceptual metric unavailable: {self.perceptual_unavailable_reason}")
        if self.perceptual_name == "stlpips-alex":
            rows.append("\nstlpips-alex is shift-tolerant LPIPS, not standard LPIPS.")
        rows.append(f"\n{len(self.items)} items.")
        return "\n".join(rows)


def _scores(pred: Tensor, gt: Tensor, perceptual: PerceptualMetric | None) -> list[ImageScores]:
    p = psnr(pred, gt).tolist()
    s = ssim(pred, gt).tolist()
    lp = perceptual(pred, gt).tolist() if perceptual is not None else [None] * len(p)
    return [ImageScores(psnr=a, ssim=b, perceptual=c) for a, b, c in zip(p, s, lp, strict=True)]


OBJECT_CROP_MIN = 64
"""Object crops smaller than this are resized up to it for the perceptual metric (its network needs
some context)."""


def _object_scores(
    pred: Tensor, gt: Tensor, mask: Tensor, perceptual: "PerceptualMetric | None"
) -> list[ImageScores]:
    p = masked_psnr(pred, gt, mask).tolist()
    s = masked_ssim(pred, gt, mask).tolist()
    lp: list[float | None] = [None] * len(p)
    if perceptual is not None:
        lp = []
        for i in range(pred.shape[0]):
            top, left, bottom, right = object_crop_box(mask[i])
            a, b = (
                pred[i : i + 1, :, top:bottom, left:right],
                gt[i : i + 1, :, top:bottom, left:right],
            )
            side = max(OBJECT_CROP_MIN, bottom - top, right - left)
            if a.shape[2:] != (side, side):
                size = (side, side)
                a = torch.nn.functional.interpolate(a, size=size, mode="bilinear", antialias=True)
                b = torch.nn.functional.interpolate(b, size=size, mode="bilinear", antialias=True)
            lp.append(float(perceptual(a.clamp(0, 1), b.clamp(0, 1))[0]))
    return [ImageScores(psnr=a, ssim=b, perceptual=c) for a, b, c in zip(p, s, lp, strict=True)]


def _mean(scores: list[ImageScores]) -> ImageScores:
    n = len(scores)
    perc = [s.perceptual for s in scores]
    return ImageScores(
        psnr=sum(s.psnr for s in scores) / n,
        ssim=sum(s.ssim for s in scores) / n,
        perceptual=None if any(v is None for v in perc) else sum(perc) / n,  # type: ignore[misc]
    )


def combine_reports(reports: "list[MetricsReport] | tuple[MetricsReport, ...]") -> MetricsReport:
    """Merge reports of disjoint batches into one (items concatenated, means over all items).

    Lets a long evaluation score batch by batch without keeping every image in memory.

    Args:
        reports: one or more reports made with the same perceptual metric and masking.

    Returns:
        The merged `MetricsReport`.

    Raises:
        ConfigError: when `reports` is empty or the reports disagree on the perceptual metric or on
            whether a mask was used.
    """
    if not reports:
        raise ConfigError("`reports` is empty; pass at least one `MetricsReport`.")
    first = reports[0]
    masked = first.mean_aligned_mask is not None
    for r in reports[1:]:
        if (
            r.perceptual_name != first.perceptual_name
            or (r.mean_aligned_mask is not None) != masked
        ):
            raise ConfigError(
                "`reports` mix perceptual metrics or masked / unmasked alignment "
                f"({first.perceptual_name!r} vs {r.perceptual_name!r}); score every batch the same way."
            )
    items = tuple(i for r in reports for i in r.items)
    return MetricsReport(
        items=items,
        mean_raw=_mean([i.raw for i in items]),
        mean_aligned_image=_mean([i.aligned_image for i in items]),
        mean_aligned_mask=_mean([i.aligned_mask for i in items if i.aligned_mask is not None])
        if masked
        else None,
        perceptual_name=first.perceptual_name,
        perceptual_unavailable_reason=first.perceptual_unavailable_reason,
        mean_object_raw=_mean([i.object_raw for i in items if i.object_raw is not None])
        if masked
        else None,
        mean_object_aligned=_mean([i.object_aligned for i in items if i.object_aligned is not None])
        if masked
        else None,
    )


def evaluate_images(
    pred: Float[Tensor, "B 3 H W"],
    gt: Float[Tensor, "B 3 H W"],
    *,
    mask: Float[Tensor, "B 1 H W"] | None = None,
    names: list[str] | None = None,
    perceptual: PerceptualMetric | Literal["auto"] | None = "auto",
) -> MetricsReport:
    """Score predictions against ground truth: raw and channel-aligned, per item and mean.

    Args:
        pred: predictions in [0, 1] (the authors score 8-bit PNGs, full image, white background).
        gt: ground truth in [0, 1].
        mask: optional object mask for the masked channel alignment.
        names: item labels; default "0", "1", ...
        perceptual: a loaded metric, None to skip, or "auto" (ST-LPIPS if it loads; otherwise the
            report says why not).

    Returns:
        A `MetricsReport`.
    """
    _check_pair(pred, gt)
    reason = None
    if perceptual == "auto":
        try:
            perceptual = load_perceptual()
        except MetricUnavailableError as exc:
            perceptual, reason = None, str(exc)
    elif perceptual is None:
        reason = "not requested"
    pred, gt = pred.float().cpu(), gt.float().cpu()
    raw = _scores(pred, gt, perceptual)
    al_img = _scores(channel_align(pred, gt), gt, perceptual)
    al_mask = obj_raw = obj_al = None
    if mask is not None:
        m = mask.float().cpu()
        aligned = channel_align(pred, gt, m)
        al_mask = _scores(aligned, gt, perceptual)
        obj_raw = _object_scores(pred, gt, m, perceptual)
        obj_al = _object_scores(aligned, gt, m, perceptual)
    labels = names or [str(i) for i in range(pred.shape[0])]
    if len(labels) != pred.shape[0]:
        raise ShapeError("names", len(labels), f"{pred.shape[0]} labels (one per item)")
    items = tuple(
        ItemMetrics(
            name=labels[i],
            raw=raw[i],
            aligned_image=al_img[i],
            aligned_mask=al_mask[i] if al_mask is not None else None,
            object_raw=obj_raw[i] if obj_raw is not None else None,
            object_aligned=obj_al[i] if obj_al is not None else None,
        )
        for i in range(pred.shape[0])
    )
    return MetricsReport(
        items=items,
        mean_raw=_mean(raw),
        mean_aligned_image=_mean(al_img),
        mean_aligned_mask=_mean(al_mask) if al_mask is not None else None,
        perceptual_name=perceptual.name if perceptual is not None else None,
        perceptual_unavailable_reason=reason,
        mean_object_raw=_mean(obj_raw) if obj_raw is not None else None,
        mean_object_aligned=_mean(obj_al) if obj_al is not None else None,
    )


def closer_than(report: MetricsReport, baseline: MetricsReport) -> float | None:
    """Share of items whose object-mask PSNR beats the baseline's on the same item (None without
    object scores, or when the reports hold different items)."""
    pairs = list(zip(report.items, baseline.items, strict=False))
    if len(report.items) != len(baseline.items) or not pairs:
        return None
    if any(a.name != b.name or a.object_raw is None or b.object_raw is None for a, b in pairs):
        return None
    wins = sum(1 for a, b in pairs if a.object_raw.psnr > b.object_raw.psnr)  # type: ignore[union-attr]
    return wins / len(pairs)
