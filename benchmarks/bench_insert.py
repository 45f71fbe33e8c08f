"""Object insertion on Blender ground truth: lighting and shadow modes of `insert`.

Scenes (`_insert_scenes.py`, rendered by Cycles in a subprocess): a procedural object of gaffer-data's
recipe standing on a shadow-catcher ground under a bundled HDRI held out from gaffer-tiny's training
and validation (`courtyard`, `sunset`: its test split), turned by a yaw. The background is the HDRI
as the camera sees it; the truth is Blender's composite (the background times the Shadow Catcher
pass, the object rendered under the same HDRI over it); the object photo is the object rendered
from the same camera under another HDRI (`forest` or `studio`), placed where the truth has it
(`--at` and `--height` from the truth's mask), so only the light and the shadow differ.

`insert_object` (the library call `gaffer-diffusion insert` makes) runs for three lightings:
`--envmap` (the true HDRI and the true camera pose), `--light-from-photo` without a key light, and
with a key light at the true map's dominant direction (`dominant_light` of the true map: its
brightest 20-degree cone; default strength and size), each with `--shadow none`, `2d` and `cycles`.
Scores: over the object (the truth's alpha > 0.5), PSNR of the insert vs the truth, raw and with
each channel's mean aligned (`metrics.channel_align`), beside the naive paste of the unrelit object
photo; over the ground near the object (a band: the truth's shadow, where its Shadow Catcher pass
darkens by more than 2%, grown by 6 px, minus the object), PSNR vs the truth beside the background
without a shadow; and the seconds of each insert (relight, place, shadow, composite).

    flock /tmp/gaffer-cpu.lock python benchmarks/bench_insert.py --threads 2 --update-baseline

Nothing here is tuned to these scenes: the modes run with their defaults (`--shadow cycles`: the
proxy from the mask and gaffer-normals' estimated normals, its albedo from the relit object).
"""

import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
import torch
from PIL import Image

NAME = "insert"
SCENE_SEED = 2026
LIGHTINGS = ("envmap", "photo", "photo+key")
SHADOWS = ("none", "2d", "cycles")
BAND_PX = 6
SHADOW_THRESHOLD = 0.98
FIGURE = common.REPO / "docs" / "_static" / "tutorial" / "insert_bench.png"


def _encode(linear: np.ndarray) -> np.ndarray:
    from gaffer_envmap.preview import srgb_encode

    return np.round(np.clip(srgb_encode(np.clip(linear, 0.0, 1.0)), 0.0, 1.0) * 255).astype(
        np.uint8
    )


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    err = ((a.astype(np.float64) - b.astype(np.float64)) / 255.0) ** 2
    mse = float(err[mask].mean())
    return float("inf") if mse == 0 else 10.0 * np.log10(1.0 / mse)


def _aligned_psnr(pred: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> float:
    from gaffer_diffusion.metrics import channel_align

    def t(x: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(x.astype(np.float32) / 255.0).permute(2, 0, 1)[None]

    m = torch.from_numpy(mask.astype(np.float32))[None, None]
    aligned = channel_align(t(pred), t(truth), m)[0].permute(1, 2, 0).numpy()
    return _psnr(np.round(aligned * 255.0), truth, mask)


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            if dy * dy + dx * dx <= r * r:
                out |= np.roll(np.roll(mask, dy, 0), dx, 1)
    return out


def _render_scenes(out: Path, threads: int, count: int) -> float:
    start = time.perf_counter()
    cmd = [sys.executable, str(Path(__file__).with_name("_insert_scenes.py")), "--out", str(out)]
    cmd += ["--seed", str(SCENE_SEED), "--threads", str(threads), "--scenes", str(count)]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - start


def run_scene(path: Path, tmp: Path, loaded: Any, sampling: Any, threads: int) -> dict[str, Any]:
    from gaffer_diffusion import insert as ins
    from gaffer_diffusion.insert_shadow_cycles import CyclesShadowConfig
    from gaffer_diffusion.photo import RelitObject, object_alpha, prepare_photo, read_photo
    from gaffer_diffusion.pipelines import RelightPipeline
    from gaffer_envmap.environment_map import EnvironmentMap
    from gaffer_envmap.poses import W2CBlender

    d = np.load(path)
    bg_lin, obj, catcher, photo = d["background"], d["object"], d["catcher"], d["photo"]
    h, w = bg_lin.shape[:2]
    truth = _encode(obj[..., :3] + (1.0 - obj[..., 3:]) * bg_lin * catcher)
    Image.fromarray(_encode(bg_lin)).save(tmp / "bg.png")
    a = np.clip(photo[..., 3:], 1e-6, 1.0)
    rgba = np.concatenate([_encode(photo[..., :3] / a), np.round(photo[..., 3:] * 255)], -1)
    Image.fromarray(rgba.astype(np.uint8), "RGBA").save(tmp / "object.png")
    background = read_photo(tmp / "bg.png")
    obj_photo = read_photo(tmp / "object.png")
    alpha = object_alpha(obj_photo, None)
    model = loaded.model
    prepared = prepare_photo(obj_photo, alpha, size=model.config.resolution)
    # the placement that puts the photo's object on the truth's pixels (same camera, same size)
    truth_mask = obj[..., 3] > 0.5
    ys, xs = np.nonzero(truth_mask)
    at = ((xs.min() + xs.max() + 1) / 2.0 - 0.5, float(ys.max()))
    placement = ins.resolve_placement(
        (w, h), ins.object_extent(alpha), at_xy=at, height_px=float(ys.max() + 1 - ys.min())
    )
    c2w = d["c2w"]
    rot = c2w[:3, :3].T
    w2c = W2CBlender(np.concatenate([rot, (-rot @ c2w[:3, 3])[:, None]], 1))
    camera = ins.BackgroundCamera(width=w, height=h, fov_deg=float(d["fov_deg"]), w2c=w2c)
    sys.path.insert(0, str(Path(__file__).parent))
    from _insert_scenes import envmap_pixels

    true_env = EnvironmentMap(
        radiance_linear=envmap_pixels(str(d["truth_hdri"]), int(d["quarter_turns"]))
    )
    dom = ins.dominant_light(true_env)
    x, y, z = dom.direction_world
    key = ins.KeyLight(
        azimuth_deg=float(np.degrees(np.arctan2(x, y)) % 360.0),
        elevation_deg=float(np.degrees(np.arcsin(np.clip(z, -1, 1)))),
    )
    lightings = {
        "envmap": ins.InsertLighting(envmap=true_env, camera=camera),
        "photo": ins.InsertLighting(
            envmap=ins.light_from_photo(background.rgb, camera, None), camera=camera
        ),
        "photo+key": ins.InsertLighting(
            envmap=ins.light_from_photo(background.rgb, camera, key), camera=camera, key_light=key
        ),
    }
    # the scores' regions
    shadow_mask = (catcher @ np.array([0.2126, 0.7152, 0.0722]) < SHADOW_THRESHOLD) & ~truth_mask
    band = _dilate(shadow_mask, BAND_PX) & ~_dilate(truth_mask, 1)
    naive_placed = ins.place_object(
        RelitObject(box=(0, 0, *alpha.shape), rgb=obj_photo.rgb, alpha=alpha),
        ins.object_extent(alpha),
        placement,
        (h, w),
    )
    naive = ins.composite(background, naive_placed, None)
    out: dict[str, Any] = {
        "scene": path.stem,
        "truth_hdri": str(d["truth_hdri"]),
        "yaw_quarter_turns": int(d["quarter_turns"]),
        "photo_hdri": str(d["photo_hdri"]),
        "object": f"gaffer-data procedural_{int(d['object_index']):03d} of seed {int(d['seed'])}",
        "key_light_from_true_map": {
            "azimuth_deg": key.azimuth_deg,
            "elevation_deg": key.elevation_deg,
        },
        "object_pixels": int(truth_mask.sum()),
        "band_pixels": int(band.sum()),
        "naive_paste": {
            "object_psnr": _psnr(naive, truth, truth_mask),
            "object_psnr_aligned": _aligned_psnr(naive, truth, truth_mask),
        },
        "background_without_shadow": {"band_psnr": _psnr(background.rgb_u8, truth, band)},
        "modes": {},
    }
    images = {"background": background.rgb_u8, "truth": truth, "naive": naive}
    pipe = RelightPipeline(model)
    for lname in LIGHTINGS:
        for shadow in SHADOWS:
            config = ins.InsertConfig(shadow=shadow, cycles=CyclesShadowConfig(threads=threads))
            start = time.perf_counter()
            res = ins.insert_object(
                pipe,
                sampling,
                prepared=prepared,
                background=background,
                lighting=lightings[lname],
                placement=placement,
                config=config,
            )
            seconds = time.perf_counter() - start
            img = res.image
            images[f"{lname}/{shadow}"] = img
            out["modes"][f"{lname}/{shadow}"] = {
                "object_psnr": _psnr(img, truth, truth_mask),
                "object_psnr_aligned": _aligned_psnr(img, truth, truth_mask),
                "band_psnr": _psnr(img, truth, band),
                "seconds": seconds,
                "shadow_seconds": res.shadow_seconds,
            }
            common.log(f"{path.stem} {lname}/{shadow}: {out['modes'][f'{lname}/{shadow}']}")
    out["_images"] = images
    return out


def _summary(scenes: list[dict[str, Any]]) -> dict[str, Any]:
    def mean(values: list[float]) -> float:
        return float(np.mean(values))

    modes = {}
    for key in scenes[0]["modes"]:
        rows = [s["modes"][key] for s in scenes]
        modes[key] = {k: mean([r[k] for r in rows]) for k in rows[0]}
    return {
        "modes": modes,
        "naive_paste": {
            k: mean([s["naive_paste"][k] for s in scenes]) for k in scenes[0]["naive_paste"]
        },
        "background_without_shadow": {
            "band_psnr": mean([s["background_without_shadow"]["band_psnr"] for s in scenes])
        },
    }


def figure(summary: dict[str, Any], meta: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colours = {"envmap": "tab:blue", "photo": "tab:orange", "photo+key": "tab:green"}
    marks = {"none": "o", "2d": "s", "cycles": "^"}
    for key, m in summary["modes"].items():
        lname, shadow = key.split("/")
        style = {"color": colours[lname], "marker": marks[shadow], "s": 60}
        axes[0].scatter(m["seconds"], m["band_psnr"], label=key, **style)
        axes[1].scatter(m["seconds"], m["object_psnr"], **style)
    axes[0].axhline(
        summary["background_without_shadow"]["band_psnr"],
        color="grey",
        ls="--",
        label="background, no shadow",
    )
    axes[1].axhline(
        summary["naive_paste"]["object_psnr"], color="grey", ls="--", label="naive paste (unrelit)"
    )
    axes[0].set_title("ground near the object: PSNR vs truth (dB)")
    axes[1].set_title("object: PSNR vs truth, raw (dB)")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("seconds per insert (log)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].legend(fontsize=7)
    fig.suptitle(
        f"insert on {meta['scenes']} Blender scenes, gaffer-tiny; {meta['device']}", fontsize=9
    )
    fig.tight_layout()
    return fig


def tutorial_figure(scene: dict[str, Any]) -> None:
    """Panels of one scene for the insert tutorial: background, truth, naive paste, and inserts."""
    names = [
        "background",
        "truth",
        "naive",
        "envmap/cycles",
        "photo+key/2d",
        "photo+key/cycles",
        "photo/2d",
        "envmap/none",
    ]
    ims = scene["_images"]
    tiles = [ims[n] for n in names]
    h = tiles[0].shape[0]
    gap = np.full((h, 4, 3), 255, np.uint8)
    rows = []
    for r in range(2):
        row = []
        for t in tiles[4 * r : 4 * r + 4]:
            row += [t, gap]
        rows.append(np.concatenate(row[:-1], 1))
    grid = np.concatenate([rows[0], np.full((4, rows[0].shape[1], 3), 255, np.uint8), rows[1]], 0)
    FIGURE.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(grid).save(FIGURE)


def main(argv: list[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    from gaffer_diffusion.demo import load_model
    from gaffer_diffusion.demo.model import sampling_for

    loaded = load_model(None)
    sampling = sampling_for(loaded, None, None)
    count = 2 if args.quick else 4
    with tempfile.TemporaryDirectory(prefix="bench_insert_") as tmp_name:
        tmp = Path(tmp_name)
        render_s = _render_scenes(tmp / "scenes", threads, count)
        scenes = [
            run_scene(tmp / "scenes" / f"scene_{i}.npz", tmp, loaded, sampling, threads)
            for i in range(count)
        ]
    tutorial_figure(scenes[0])
    for s in scenes:
        s.pop("_images")
    summary = _summary(scenes)
    meta["scenes"] = count
    payload = {
        "name": NAME,
        "description": __doc__,
        "machine": meta,
        "model": common.model_provenance(),
        "sampling": {
            "num_inference_steps": sampling.num_inference_steps,
            "guidance_scale": sampling.guidance_scale,
        },
        "settings": {
            "scene_seed": SCENE_SEED,
            "resolution": [256, 192],
            "truth_samples": 64,
            "held_out_hdris": ["courtyard", "sunset"],
            "photo_hdris": ["forest", "studio"],
            "cycles_shadow": {
                "size": 256,
                "samples": 32,
                "denoise": True,
                "threads": threads,
                "proxy": "auto (the mask and gaffer-normals' estimated normals; albedo from the object)",
            },
            "band_px": BAND_PX,
            "shadow_threshold": SHADOW_THRESHOLD,
        },
        "scene_render_seconds": render_s,
        "summary": summary,
        "scenes": scenes,
        "tutorial_figure": str(FIGURE.relative_to(common.REPO)),
    }
    written = common.write_results(NAME, payload, figure(summary, meta), args.update_baseline)
    for key, m in summary["modes"].items():
        print(
            f"{key:18s} object {m['object_psnr']:.2f}/{m['object_psnr_aligned']:.2f} dB  "
            f"band {m['band_psnr']:.2f} dB  {m['seconds']:.2f} s"
        )
    n, b = summary["naive_paste"], summary["background_without_shadow"]
    print(
        f"naive paste object {n['object_psnr']:.2f}/{n['object_psnr_aligned']:.2f} dB; "
        f"background band {b['band_psnr']:.2f} dB"
    )
    print("wrote", *written)
    return 0


if __name__ == "__main__":
    sys.exit(main())
