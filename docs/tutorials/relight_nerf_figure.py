"""Figure of the relight-a-NeRF tutorial (section 4), run in the folder of its commands.

Each test view of procedural_000 cropped to the object, one per row: the Cycles render under the input
lighting (index 1, city), the fitted field, the relit field, the Cycles render under the target
(index 0, courtyard); writes relight-nerf-real.png.
"""

import json
from pathlib import Path

import numpy as np
from PIL import Image

OBJECT = Path("mv/objects/procedural_000")
TILE = 96
GAP = 4


def cycles(frame: dict, lighting: int) -> tuple[np.ndarray, np.ndarray]:
    """A Cycles render of the test view over white, and its alpha."""
    path = OBJECT / f"{frame['lit'][lighting]['file_path']}.png"
    rgba = np.asarray(Image.open(path).convert("RGBA"), np.float32) / 255
    return rgba[..., :3] * rgba[..., 3:] + (1 - rgba[..., 3:]), rgba[..., 3]


def render(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"), np.float32) / 255


def tile(image: np.ndarray, box: tuple[int, int, int]) -> np.ndarray:
    top, left, side = box
    u8 = (image[top : top + side, left : left + side] * 255 + 0.5).astype(np.uint8)
    return np.asarray(Image.fromarray(u8).resize((TILE, TILE), Image.Resampling.NEAREST))


def main() -> None:
    frames = json.loads((OBJECT / "transforms_test.json").read_text())["frames"]
    names = sorted(p.name for p in Path("renders_relit").glob("*.png"))
    rows = []
    for frame, name in zip(frames, names, strict=True):
        source, alpha = cycles(frame, 1)
        target, _ = cycles(frame, 0)
        ys, xs = np.nonzero(alpha > 0.05)
        half = max(ys.max() - ys.min(), xs.max() - xs.min()) // 2 + 4
        cy, cx = (ys.min() + ys.max()) // 2, (xs.min() + xs.max()) // 2
        box = (max(cy - half, 0), max(cx - half, 0), 2 * half)
        images = [
            source,
            render(Path("renders_field") / name),
            render(Path("renders_relit") / name),
            target,
        ]
        gap = np.full((TILE, GAP, 3), 255, np.uint8)
        parts: list[np.ndarray] = []
        for image in images:
            parts += [tile(image, box), gap]
        rows += [np.concatenate(parts[:-1], axis=1)]
    width = rows[0].shape[1]
    spaced: list[np.ndarray] = []
    for row in rows:
        spaced += [row, np.full((GAP, width, 3), 255, np.uint8)]
    grid = np.concatenate(spaced[:-1], axis=0)
    Image.fromarray(grid).save("relight-nerf-real.png", optimize=True)
    print(f"wrote relight-nerf-real.png ({grid.shape[1]}x{grid.shape[0]})")


if __name__ == "__main__":
    main()
