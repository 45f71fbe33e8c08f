"""Synthetic rendered datasets for tests: gaffer-data's on-disk layout without Blender.

`write_authors_release` writes the authors' released layout instead (to convert with `gaffer-data
convert-authors`).

Each object is a flat disc of one albedo; its image under an environment map is the disc shaded by the
map's mean colour (a crude but learnable "relighting"), composited with a straight alpha on a
transparent film. The folders are written by gaffer-data's own fake-dataset writer
(`gaffer_data.testing.write_fake_object`, `write_fake_dataset_json`), so `gaffer_data.open_dataset`
reads them like real renders.
"""

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gaffer_data import RenderConfig
from gaffer_data.dataset import (
    AreaLightImage,
    AreaLightSample,
    CameraSample,
    EnvmapRef,
    Intrinsics,
    LitImage,
    ObjectPlan,
    ViewRecord,
)
from gaffer_data.testing import write_fake_dataset_json, write_fake_object
from gaffer_envmap.writers import quantize, write_png

if TYPE_CHECKING:
    from gaffer_diffusion.training.config import TrainConfig


def write_envmaps(
    folder: Path, count: int = 4, height: int = 8, *, seed: int = 0, peak: float | None = None
) -> list[Path]:
    """`count` random `[height, 2 height]` EXR maps (one with a bright sun of `peak` if given)."""
    from gaffer_envmap.io import write_envmap

    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(count):
        colour = rng.uniform(0.1, 1.5, size=3).astype(np.float32)
        env = np.broadcast_to(colour, (height, 2 * height, 3)).copy()
        env[: height // 2] *= 1.5  # brighter sky
        if peak is not None and k == 0:
            env[1, 3] = peak
        p = folder / f"env{k}.exr"
        write_envmap(p, env)
        paths.append(p)
    return paths


def _disc_rgba(size: int, albedo: np.ndarray, light: np.ndarray) -> np.ndarray:
    yy, xx = np.mgrid[0:size, 0:size]
    r = np.hypot(xx - size / 2 + 0.5, yy - size / 2 + 0.5) / (size / 2)
    alpha = np.clip((0.8 - r) * size / 2, 0.0, 1.0)
    shade = np.clip(albedo * light, 0.0, 1.0) ** (1 / 2.2)
    rgb = np.broadcast_to(shade, (size, size, 3)) * (0.6 + 0.4 * (1 - r[..., None]))
    return np.concatenate([rgb, alpha[..., None]], axis=-1)


def _save_png(path: Path, rgba: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, rgba)


def write_synthetic_dataset(
    root: Path,
    *,
    objects: int = 3,
    views: int = 2,
    lightings: int = 3,
    size: int = 32,
    envmaps: int = 4,
    envmap_height: int = 8,
    area: bool = True,
    seed: int = 0,
    sun_peak: float | None = None,
) -> Path:
    """Write a dataset folder readable by `gaffer_data.open_dataset`; returns `root`.

    Args:
        root: dataset folder (its `envmaps/` sub-folder holds the maps).
        objects: number of objects (ids `obj0`, `obj1`, ...).
        views: views per object.
        lightings: environment-map renders per view.
        size: image side in pixels.
        envmaps: size of the lighting pool.
        envmap_height: pool map height (width 2x).
        area: also write the area-light render of each view.
        seed: seed of albedos, draws and poses.
        sun_peak: radiance of a one-pixel sun in the first map (stability tests).
    """
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.poses import orbit_w2c_blender

    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    pool = write_envmaps(root / "envmaps", envmaps, envmap_height, seed=seed, peak=sun_peak)
    means = [
        np.minimum(read_envmap(p, sanitize="clamp").radiance_linear.mean(axis=(0, 1)), 4.0)
        for p in pool
    ]
    cfg = RenderConfig(
        views=views, lightings=lightings, resolution=size, samples=1, area_light_render=area
    )
    ids = []
    for o in range(objects):
        oid = f"obj{o}"
        ids.append(oid)
        folder = root / "objects" / oid
        albedo = rng.uniform(0.2, 0.9, size=3)
        pngs: dict[str, np.ndarray] = {}
        view_records = []
        w2cs, c2ws = [], []
        for v in range(views):
            az, el = float(rng.uniform(0, 360)), float(rng.uniform(-30, 60))
            pose = orbit_w2c_blender(az, el, 2.0)
            w2cs.append(pose.matrix)
            c2ws.append(pose.to_c2w_opencv().matrix)
            lits = []
            for li in range(lightings):
                k = int(rng.integers(len(pool)))
                rel = f"lit/{v:03d}_{li:03d}"
                pngs[f"{rel}.png"] = quantize(_disc_rgba(size, albedo, means[k]))
                ref = EnvmapRef(
                    name=pool[k].stem,
                    source=str(pool[k]),
                    source_sha256="0" * 64,
                    flip=bool(rng.integers(2)),
                    yaw_step=int(rng.integers(4)),
                    num_steps=4,
                )
                lits.append(
                    LitImage(lighting_index=li, envmap=ref, exr=f"{rel}.exr", png=f"{rel}.png")
                )
            area_rec = None
            if area:
                pngs[f"area/{v:03d}.png"] = quantize(_disc_rgba(size, albedo, np.full(3, 0.7)))
                area_rec = AreaLightImage(
                    light=AreaLightSample(
                        location=(0.0, 0.0, 1.0), energy=400.0, scale=100.0, world_grey=0.35
                    ),
                    exr=f"area/{v:03d}.exr",
                    png=f"area/{v:03d}.png",
                    normal=f"normal/{v:03d}.exr",
                    albedo=f"albedo/{v:03d}.exr",
                    depth=f"depth/{v:03d}.exr",
                )
            view_records.append(
                ViewRecord(
                    index=v,
                    camera=CameraSample(
                        elevation_deg=el, azimuth_deg=az, distance=2.0, position=(0.0, 0.0, 0.0)
                    ),
                    lit=tuple(lits),
                    area=area_rec,
                    alpha=None,
                )
            )
        k_mat = np.array([[size, 0, size / 2], [0, size, size / 2], [0, 0, 1]], np.float64)
        plan = ObjectPlan(
            object_id=oid,
            source=f"/synthetic/{oid}.glb",
            views=tuple(view_records),
            intrinsics=Intrinsics(
                width=size, height=size, fx=size, fy=size, cx=size / 2, cy=size / 2
            ),
            config=cfg,
        )
        write_fake_object(
            folder,
            plan,
            pngs=pngs,
            w2c_blender=np.stack(w2cs),
            c2w_opencv=np.stack(c2ws),
            intrinsics=k_mat,
            record_files=False,
        )
    write_fake_dataset_json(root, cfg, ids)
    return root


def write_authors_release(
    root: Path,
    *,
    objects: int = 2,
    views: int = 2,
    lightings: int = 3,
    size: int = 32,
    map_size: int = 24,
    area: bool = True,
    seed: int = 0,
) -> Path:
    """A tiny split in the authors' released layout; returns the split folder `root`.

    Per object `objK/`: `{VVV}_RT.npy`, `{VVV}_{LLL}_{env}.png` (RGBA discs shaded by the lighting's
    colour), `random_lighting_{VVV}.png` (with `area`) and the camera-frame maps `LDR/` and
    `HDR_rescaled/` (same names, RGB `map_size` squares: the colour over a random texture), inside the
    object folder as in some of the authors' archives. Convert it with
    `gaffer_data.convert.convert_authors(root, out)`.
    """
    from gaffer_envmap.poses import orbit_w2c_blender

    rng = np.random.default_rng(seed)
    names = ("sky_000", "sky_090", "cave_045", "sun_180", "dusk_270")
    for o in range(objects):
        folder = root / f"obj{o}"
        folder.mkdir(parents=True, exist_ok=True)
        albedo = rng.uniform(0.2, 0.9, size=3)
        for v in range(views):
            pose = orbit_w2c_blender(float(rng.uniform(0, 360)), float(rng.uniform(-30, 60)), 2.0)
            np.save(folder / f"{v:03d}_RT.npy", pose.matrix)
            if area:
                rgba = _disc_rgba(size, albedo, np.full(3, 0.7))
                _save_png(folder / f"random_lighting_{v:03d}.png", rgba)
            for li in range(lightings):
                colour = rng.uniform(0.1, 1.5, size=3)
                name = f"{v:03d}_{li:03d}_{names[li % len(names)]}.png"
                _save_png(folder / name, _disc_rgba(size, albedo, colour))
                texture = rng.uniform(0.0, 0.3, size=(map_size, map_size, 1))
                ldr = np.clip(np.minimum(colour, 1.0) ** (1 / 2.2) * 0.7 + texture, 0, 1)
                hdr = np.clip(np.log1p(10 * colour) / np.log1p(15.0) * 0.7 + texture, 0, 1)
                for sub, arr in (("LDR", ldr), ("HDR_rescaled", hdr)):
                    path = folder / sub / name
                    path.parent.mkdir(parents=True, exist_ok=True)
                    write_png(path, arr)
    return root


def tiny_train_config(out: Path, root: Path, **sections: dict[str, Any]) -> "TrainConfig":
    """A seconds-long CPU training config: the `tiny` preset at 32 px on `root`, 4 steps of batch 2,
    checkpoints every 2 steps, no validation. `sections` override keys per section, e.g.
    `train={"max_steps": 6}`."""
    from gaffer_diffusion.training.config import TrainConfig

    base: dict[str, Any] = {
        "output_dir": str(out),
        "model": {"init": "preset", "preset": "tiny", "resolution": 32},
        "data": {"root": str(root), "val_objects": 1, "envmap_height": 8},
        "optim": {"lr": 1e-3, "warmup_steps": 2},
        "train": {
            "max_steps": 4,
            "batch_size": 2,
            "mixed_precision": "no",
            "gradient_checkpointing": False,
            "ema_decay": 0.9,
        },
        "checkpoint": {"every_steps": 2, "keep": 2},
        "logging": {"every_steps": 1, "progress_bar": False, "tensorboard": False},
        "validation": {"every_steps": 0},
    }
    for k, v in sections.items():
        base[k] = {**base.get(k, {}), **v} if isinstance(v, dict) else v
    return TrainConfig.from_dict(base)
