"""Figure of the insert tutorial: the shipped example object put into a view of a bundled HDRI.

Run from any folder (`python docs/tutorials/insert_figure.py OUT_DIR`): it renders the background (a
level camera looking along world +y at the bundled `courtyard`, 39.6 degrees wide), runs
`gaffer-diffusion insert` six ways (a key light from the right with the pixel-height shadow and with
`--shadow cycles`, from the left, the true map with `--envmap courtyard` with each shadow, no shadow)
and writes `OUT_DIR/insert.png`: two rows of four panels, the background first and the map built from
it (`--save-envmap`, tone-mapped) last. The `cycles` panels need bpy (`gaffer-data[render]`); without
it they are left out, and the rows hold three panels.
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import main
from gaffer_diffusion.insert import LEVEL_CAMERA
from gaffer_diffusion.insert_shadow_cycles import bpy_available
from gaffer_diffusion.photo import envmap_backdrop
from gaffer_envmap.bundled import read_bundled_hdri
from gaffer_envmap.io import read_envmap
from gaffer_envmap.preview import srgb_encode

W, H = 384, 288
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
RUNS = {
    "key_right": ["--key-light", "120,35", "--save-envmap", "{out}/light.exr"],
    "key_right_cycles": ["--key-light", "120,35", "--shadow", "cycles"],
    "key_left": ["--key-light", "240,35"],
    "envmap": ["--envmap", "courtyard"],
    "envmap_cycles": ["--envmap", "courtyard", "--shadow", "cycles"],
    "no_shadow": ["--key-light", "120,35", "--shadow", "none"],
}


def main_figure(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, LEVEL_CAMERA.rotation, height=H, width=W)
    background = out / "background.png"
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(background)
    panels = [np.asarray(Image.open(background).convert("RGB"))]
    runs = {k: v for k, v in RUNS.items() if bpy_available() or "cycles" not in v}
    for name, extra in runs.items():
        dest = out / f"{name}.png"
        argv = ["insert", str(OBJECT), "--into", str(background), "--out", str(dest)]
        extra = [a.format(out=out) for a in extra]
        assert main([*argv, "--at", "200,250", "--height", "110", *extra]) == 0
        panels.append(np.asarray(Image.open(dest).convert("RGB")))
    light = read_envmap(out / "light.exr").radiance_linear
    shown = srgb_encode(np.clip(light / np.percentile(light, 99), 0.0, 1.0))
    shown = Image.fromarray(np.round(shown * 255).astype(np.uint8)).resize((W, W // 2))
    panel = np.full((H, W, 3), 255, np.uint8)
    panel[(H - W // 2) // 2 : (H - W // 2) // 2 + W // 2] = np.asarray(shown)
    panels.append(panel)
    gap = np.full((H, 6, 3), 255, np.uint8)
    k = len(panels) // 2
    rows = [
        np.concatenate([p for q in panels[i : i + k] for p in (q, gap)][:-1], 1) for i in (0, k)
    ]
    grid = np.concatenate([rows[0], np.full((6, rows[0].shape[1], 3), 255, np.uint8), rows[1]], 0)
    Image.fromarray(grid).save(out / "insert.png")


if __name__ == "__main__":
    main_figure(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
