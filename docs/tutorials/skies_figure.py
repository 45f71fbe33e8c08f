"""Figure of the skies tutorial: four maps of `gaffer-envmap sky` and the example object in each.

Run from any folder (`python docs/tutorials/skies_figure.py OUT_DIR`): it writes four maps with
`gaffer-envmap sky` (a sun by its angles; three phrases of the grammar: a golden hour from the left,
an overcast morning, a softbox from the left with a rim light), renders what a level camera looking
along world +y sees of each (39.6 degrees wide) as a background, inserts the shipped example object
into it with `gaffer-diffusion insert --envmap MAP` (`--shadow cycles` where bpy is installed, else
`--shadow 2d`), and writes `OUT_DIR/skies.png`: the tone-mapped maps on the first row (the middle is
straight ahead, behind the object; the right half's middle is the light from the right), the
inserts below.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import main as diffusion_main
from gaffer_diffusion.insert import LEVEL_CAMERA
from gaffer_diffusion.photo import envmap_backdrop
from gaffer_envmap.cli import main as envmap_main
from gaffer_envmap.io import read_envmap
from gaffer_envmap.preview import srgb_encode

W, H = 256, 192
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
SKIES = {
    "angles": ["--sun-elevation", "35", "--sun-azimuth", "120"],
    "golden": ["--text", "golden hour from the left"],
    "overcast": ["--text", "overcast morning"],
    "studio": ["--text", "softbox from the left and a rim light"],
}
SHADOW = "cycles" if importlib.util.find_spec("bpy") is not None else "2d"


def _u8(x: np.ndarray) -> np.ndarray:
    return np.round(np.clip(x, 0.0, 1.0) * 255).astype(np.uint8)


def main_figure(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    maps, inserts = [], []
    for name, flags in SKIES.items():
        exr = out / f"{name}.exr"
        assert envmap_main(["sky", *flags, "--width", "512", "--out", str(exr)]) == 0
        env = read_envmap(exr).radiance_linear
        shown = srgb_encode(np.clip(env / np.percentile(env, 99), 0.0, 1.0))
        panel = np.full((H, W, 3), 255, np.uint8)
        top = (H - W // 2) // 2
        panel[top : top + W // 2] = np.asarray(Image.fromarray(_u8(shown)).resize((W, W // 2)))
        maps.append(panel)
        view = envmap_backdrop(env, LEVEL_CAMERA.rotation, height=H, width=W)
        background = out / f"{name}_background.png"
        Image.fromarray(_u8(view)).save(background)
        dest = out / f"{name}_insert.png"
        argv = ["insert", str(OBJECT), "--into", str(background), "--out", str(dest)]
        argv += ["--envmap", str(exr), "--at", "128,170", "--height", "90", "--shadow", SHADOW]
        assert diffusion_main(argv) == 0
        inserts.append(np.asarray(Image.open(dest).convert("RGB")))
    gap = np.full((H, 6, 3), 255, np.uint8)

    def row(panels: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([p for q in panels for p in (q, gap)][:-1], 1)

    rows = [row(maps), row(inserts)]
    grid = np.concatenate([rows[0], np.full((6, rows[0].shape[1], 3), 255, np.uint8), rows[1]], 0)
    Image.fromarray(grid).save(out / "skies.png")


if __name__ == "__main__":
    main_figure(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
