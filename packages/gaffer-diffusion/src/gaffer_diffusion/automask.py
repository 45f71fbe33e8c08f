"""Offline foreground masks for photos without alpha: GrabCut, or SAM when installed.

`grabcut_mask` is a classical fallback, not a learned segmenter: OpenCV's GrabCut (Rother, Kolmogorov and
Blake, SIGGRAPH 2004) seeded with the photo's border as background and, inside a centred box, the pixels
that a smooth backdrop fitted to the border does not explain as probable foreground (the whole box
when there are none), the connected region nearest the middle kept (thin bridges opened first) and holes closed, then the edge refined at full resolution
by a guided filter steered by the photo (soft alpha along the object's real edges). It needs the `photo`
extra (`opencv-python-headless`) and no weights.

`sam_mask` uses Segment Anything (`segment-anything` and a local checkpoint, as the authors' demo does),
prompted with the same centred box.
"""

from pathlib import Path

import numpy as np

from gaffer_diffusion.detail_transfer import guided_filter, luma
from gaffer_diffusion.errors import InputValueError, MissingDependencyError

GRABCUT_MAX_SIDE = 320
"""GrabCut runs on the photo shrunk to this longer side (its cost grows with pixels); the edge is then
refined at full size."""

BORDER_FRACTION = 0.03
"""Width of the border strip taken as sure background, as a fraction of the shorter side."""

BOX_FRACTION = 0.8
"""The centred box seeded as probable foreground spans this fraction of each side."""

GRABCUT_ITERATIONS = 5


def require_opencv():
    """`cv2`, or a one-line error naming the `photo` extra."""
    try:
        import cv2
    except ImportError as exc:
        raise MissingDependencyError(
            '`--mask auto` needs OpenCV: pip install "gaffer-diffusion[photo]" '
            "(opencv-python-headless), or pass `--mask MASK.png`."
        ) from exc
    return cv2


def centred_box(height: int, width: int) -> tuple[int, int, int, int]:
    """`(x0, y0, x1, y1)` of the centred box spanning `BOX_FRACTION` of each side."""
    mx, my = int(width * (1 - BOX_FRACTION) / 2), int(height * (1 - BOX_FRACTION) / 2)
    return mx, my, width - mx, height - my


def _unlike_border(rgb: np.ndarray, border: int) -> np.ndarray:
    """Pixels that a smooth backdrop fitted to the border strip does not explain.

    GrabCut's colour models miss a backdrop whose colour drifts across the picture (a studio sweep,
    vignetting, sky): the middle of the gradient is a colour the border never shows. A quadratic
    surface per channel fitted to the border pixels predicts the backdrop everywhere; pixels far from
    it (over 3 robust sigmas of the border's own residual, and over 0.06) seed the object.
    """
    h, w = rgb.shape[:2]
    yy, xx = np.mgrid[:h, :w].astype(np.float32)
    yy, xx = yy / max(h - 1, 1) - 0.5, xx / max(w - 1, 1) - 0.5
    basis = np.stack([np.ones_like(xx), xx, yy, xx * xx, xx * yy, yy * yy], -1)  # [h, w, 6]
    ring = np.zeros((h, w), bool)
    ring[:border], ring[-border:], ring[:, :border], ring[:, -border:] = True, True, True, True
    coef, *_ = np.linalg.lstsq(basis[ring], rgb[ring], rcond=None)  # [6, 3]
    resid = np.linalg.norm(rgb - basis @ coef, axis=-1)
    r = resid[ring]
    sigma = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return resid > max(float(np.median(r)) + 3.0 * sigma, 0.06)


def grabcut_mask(rgb_u8: np.ndarray, *, iterations: int = GRABCUT_ITERATIONS) -> np.ndarray:
    """A classical foreground estimate of a photo of one roughly centred object.

    Args:
        rgb_u8: `[H, W, 3]` uint8 sRGB photo.
        iterations: GrabCut iterations.

    Returns:
        `[H, W]` float32 soft mask in [0, 1] (white = object).

    Raises:
        MissingDependencyError: OpenCV is not installed.
        InputValueError: when GrabCut finds no object.
    """
    cv2 = require_opencv()
    h, w = rgb_u8.shape[:2]
    k = min(1.0, GRABCUT_MAX_SIDE / max(h, w))
    sw, sh = max(round(w * k), 8), max(round(h * k), 8)
    small = cv2.resize(np.ascontiguousarray(rgb_u8), (sw, sh), interpolation=cv2.INTER_AREA)
    bgr = np.ascontiguousarray(small[..., ::-1])
    seed = np.full((sh, sw), cv2.GC_PR_BGD, np.uint8)
    x0, y0, x1, y1 = centred_box(sh, sw)
    b = max(round(min(sh, sw) * BORDER_FRACTION), 1)
    unlike = _unlike_border(small.astype(np.float32) / 255.0, b)
    unlike[:, :x0], unlike[:, x1:], unlike[:y0], unlike[y1:] = False, False, False, False
    if unlike.sum() >= 16:
        seed[unlike] = cv2.GC_PR_FGD  # pixels the border's smooth backdrop does not explain
    else:
        seed[y0:y1, x0:x1] = cv2.GC_PR_FGD
    seed[:b], seed[-b:], seed[:, :b], seed[:, -b:] = (cv2.GC_BGD,) * 4
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.setRNGSeed(0)
    cv2.grabCut(bgr, seed, (0, 0, 0, 0), bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    fg = ((seed == cv2.GC_FGD) | (seed == cv2.GC_PR_FGD)).astype(np.uint8)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    opened = cv2.morphologyEx(fg, cv2.MORPH_OPEN, kernel)  # break thin bridges to the clutter
    fg = opened if opened.any() else fg
    n, labels = cv2.connectedComponents(fg, connectivity=8)
    if n <= 1:
        raise InputValueError(
            "`--mask auto` found no object (GrabCut, a classical fallback, expects one object roughly "
            "in the middle of the photo): pass `--mask MASK.png` (white = object)."
        )
    # the region nearest the middle: pixel count weighted by closeness to the centre
    yy, xx = np.mgrid[:sh, :sw]
    near = np.exp(-(((yy - sh / 2) / (sh / 4)) ** 2 + ((xx - sw / 2) / (sw / 4)) ** 2))
    score = np.bincount(labels.ravel(), weights=near.ravel(), minlength=n)[1:]
    best = 1 + int(np.argmax(score))
    fg = (labels == best).astype(np.uint8)
    fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, kernel)
    # fill holes: everything not reachable from the border through background is object
    flood = (1 - fg).astype(np.uint8)
    ff = np.zeros((sh + 2, sw + 2), np.uint8)
    flood_img = flood.copy()
    cv2.floodFill(flood_img, ff, (0, 0), (2,))
    fg = np.where(flood_img == 2, 0, 1).astype(np.float32)
    full = cv2.resize(fg, (w, h), interpolation=cv2.INTER_LINEAR)
    # edge refinement at full size: a guided filter steered by the photo (soft alpha on real edges)
    radius = max(round(2 / k), 2)
    soft = guided_filter(luma(rgb_u8.astype(np.float32) / 255.0), full, radius, 1e-4)
    return np.clip(soft, 0.0, 1.0).astype(np.float32)


def sam_mask(rgb_u8: np.ndarray, checkpoint: str | Path) -> np.ndarray:
    """Segment Anything's mask for the object in the centred box (`segment-anything` + a local checkpoint).

    The model type (vit_h / vit_l / vit_b) is read from the checkpoint's file name, as the official files
    are named (`sam_vit_h_4b8939.pth`); vit_h otherwise.

    Raises:
        MissingDependencyError: `segment-anything` is not installed.
        InputValueError: the checkpoint file is missing.
    """
    try:
        from segment_anything import (  # pyright: ignore[reportMissingImports]
            SamPredictor,
            sam_model_registry,
        )
    except ImportError as exc:
        raise MissingDependencyError(
            "`--sam-checkpoint` needs segment-anything, which is not installed: "
            "pip install segment-anything (or use `--mask auto`, the classical GrabCut fallback)."
        ) from exc
    ckpt = Path(checkpoint)
    if not ckpt.is_file():
        raise InputValueError(f"`--sam-checkpoint` {ckpt} is not a file.")
    kind = next((k for k in ("vit_h", "vit_l", "vit_b") if k in ckpt.name), "vit_h")
    predictor = SamPredictor(sam_model_registry[kind](checkpoint=str(ckpt)))
    predictor.set_image(np.ascontiguousarray(rgb_u8))
    h, w = rgb_u8.shape[:2]
    masks, scores, _ = predictor.predict(box=np.array(centred_box(h, w)), multimask_output=True)
    return masks[int(np.argmax(scores))].astype(np.float32)
