"""Display helpers: tone-map linear radiance to sRGB 8-bit and lay images out on a labelled sheet."""

import numpy as np
from PIL import Image, ImageDraw

from gaffer_envmap.writers import quantize


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """The sRGB transfer curve (IEC 61966-2-1) on [0, 1] linear values."""
    x = np.clip(linear, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def tonemap_preview(radiance_linear: np.ndarray, exposure: float | None = None) -> np.ndarray:
    """`[H, W, 3]` uint8 sRGB preview: exposure to put the median luminance at 0.18, Reinhard, sRGB.

    NaN/Inf are drawn black. Deterministic (no randomness), `gaffer_envmap.writers.quantize`d.
    """
    x = np.nan_to_num(
        np.asarray(radiance_linear, np.float64), nan=0.0, posinf=0.0, neginf=0.0
    ).clip(0, None)
    if exposure is None:
        lum = x @ np.array([0.2126, 0.7152, 0.0722])
        med = float(np.median(lum))
        exposure = 0.18 / med if med > 0 else 1.0
    y = x * exposure
    return quantize(srgb_encode(y / (1.0 + y)))


def contact_sheet(
    rows: list[list[tuple[str, np.ndarray]]], cell: int = 192, pad: int = 6
) -> np.ndarray:
    """Grid of labelled uint8 RGB images (each scaled to `cell` px high, aspect kept)."""
    label_h = 14
    rendered: list[list[Image.Image]] = []
    for row in rows:
        out = []
        for label, img in row:
            im = Image.fromarray(img)
            w = max(1, round(im.width * cell / im.height))
            im = im.resize(
                (w, cell),
                Image.Resampling.NEAREST if im.height < cell else Image.Resampling.BILINEAR,
            )
            tile = Image.new("RGB", (w, cell + label_h), (255, 255, 255))
            tile.paste(im, (0, label_h))
            ImageDraw.Draw(tile).text((2, 1), label, fill=(0, 0, 0))
            out.append(tile)
        rendered.append(out)
    width = max(sum(t.width for t in row) + pad * (len(row) + 1) for row in rendered)
    height = sum(row[0].height for row in rendered) + pad * (len(rendered) + 1)
    sheet = Image.new("RGB", (width, height), (255, 255, 255))
    y = pad
    for row in rendered:
        x = pad
        for tile in row:
            sheet.paste(tile, (x, y))
            x += tile.width + pad
        y += row[0].height + pad
    return np.asarray(sheet)
