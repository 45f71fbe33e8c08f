"""Public test helpers: an analytically rendered multi-view scene with ground truth under every lighting.

A Lambertian sphere (radius 0.5 at the origin, a smooth colour pattern painted on it) lit by a smooth
environment map, rendered exactly per pixel: radiance = albedo x irradiance(n) / pi, with the irradiance
from gaffer-envmap's order-2 spherical harmonics (exact for a Lambertian up to the map's band limit).
Images are sRGB 8-bit PNGs with straight alpha, and `transforms_{train,test}.json` are written in
gaffer-data's multi-view layout (NeRF-Synthetic + `lit` + `lightings`), so the whole reader -> fit ->
relight -> evaluate chain runs without Blender. Nothing here downloads anything.
"""

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from gaffer_envmap import EnvironmentMap, orbit_w2c_blender, write_envmap
from gaffer_envmap.sh import irradiance
from gaffer_envmap.testing import smooth_random_map
from gaffer_envmap.writers import quantize_float, write_png
from gaffer_nerf.cameras import Cameras
from gaffer_nerf.configs import FitConfig, fit_preset
from gaffer_nerf.data.transforms import BLENDER_TO_OPENCV, ViewSet

SPHERE_RADIUS = 0.5


@dataclass(frozen=True, kw_only=True)
class SyntheticScene:
    """Where `write_sphere_scene` put things.

    Attributes:
        root: the scene folder (transforms files, `lit/` PNGs).
        envmap_dir: folder of the lighting EXRs (`env0.exr`, `env1.exr`, ...).
        envmaps: the world-frame maps, lighting index order.
        train_views: number of training views.
        test_views: number of test views.
    """

    root: Path
    envmap_dir: Path
    envmaps: tuple[EnvironmentMap, ...]
    train_views: int
    test_views: int


def scene_envmap(seed: int, height: int = 16) -> EnvironmentMap:
    """A smooth positive map, scaled so the sphere's brightest irradiance / pi is 1."""
    env = smooth_random_map(height, seed=seed, lobes=4)
    dirs = np.random.default_rng(0).normal(size=(256, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    peak = float((irradiance(env, dirs) / math.pi).max())
    return env.with_radiance(env.radiance_linear / max(peak, 1e-6))


def albedo(points: np.ndarray) -> np.ndarray:
    """The painted pattern: `[..., 3]` albedo in [0.15, 0.85] at points on the sphere."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    phi = np.arctan2(y, x)
    return np.stack(
        [
            0.5 + 0.35 * np.sin(2 * phi),
            0.5 + 0.35 * np.cos(3 * z / SPHERE_RADIUS),
            0.5 + 0.35 * np.sin(phi + 2 * z / SPHERE_RADIUS),
        ],
        axis=-1,
    )


def orbit_cameras(
    num_views: int,
    *,
    resolution: int = 64,
    distance: float = 2.5,
    fov_deg: float = 40.0,
    offset_deg: float = 0.0,
) -> Cameras:
    """Cameras on an orbit around the origin, elevations alternating 10..50 degrees."""
    f = 0.5 * resolution / math.tan(math.radians(fov_deg) / 2)
    c2w = []
    for k in range(num_views):
        az = offset_deg + 360.0 * k / num_views
        el = 10.0 + 40.0 * ((k * 0.618034) % 1.0)
        c2w.append(orbit_w2c_blender(az, el, distance).to_c2w_opencv().matrix)
    v = num_views
    return Cameras(
        c2w_opencv=torch.from_numpy(np.stack(c2w)).float(),
        focal_px=torch.full((v, 2), f),
        principal_px=torch.full((v, 2), resolution / 2.0),
        width=resolution,
        height=resolution,
    )


PLAIN_ALBEDO = 0.6


def render_sphere(
    cameras: Cameras, env: EnvironmentMap, *, empty: bool = False, plain: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Exact renders of the painted sphere.

    Args:
        cameras: the views.
        env: world-frame lighting (Blender convention).
        empty: render no object (every pixel background), for the "no object" stability case.
        plain: paint no pattern (albedo `PLAIN_ALBEDO` everywhere): a scene that needs low VM ranks.

    Returns:
        `[V, H, W, 3]` straight sRGB in [0, 1] (0 where alpha is 0) and `[V, H, W]` alpha in {0, 1}.
    """
    rays = cameras.rays()
    o = rays.origins_world.double().numpy()
    d = rays.dirs_world.double().numpy()
    b = (o * d).sum(-1)
    c = (o * o).sum(-1) - SPHERE_RADIUS**2
    disc = b * b - c
    hit = (disc > 0) & (not empty)
    t = -b - np.sqrt(np.clip(disc, 0, None))
    p = o + d * t[:, None]
    n = p / SPHERE_RADIUS
    rgb_linear = np.zeros_like(p)
    if hit.any():
        rho = np.full_like(p[hit], PLAIN_ALBEDO) if plain else albedo(p[hit])
        rgb_linear[hit] = rho * irradiance(env, n[hit]) / math.pi
    rgb_srgb = _srgb(np.clip(rgb_linear, 0.0, 1.0)) * hit[:, None]
    shape = (cameras.num_views, cameras.height, cameras.width)
    return rgb_srgb.reshape(*shape, 3), hit.reshape(shape).astype(np.float64)


def _srgb(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)


def quantize8(x: np.ndarray) -> np.ndarray:
    """Round to 8 bit and back, as a PNG round trip does (`gaffer_envmap.writers.quantize_float`)."""
    return quantize_float(x)


def sphere_viewset(
    cameras: Cameras,
    env: EnvironmentMap,
    *,
    lighting_index: int = 0,
    empty: bool = False,
    plain: bool = False,
) -> ViewSet:
    """An in-memory `ViewSet` of the sphere (composited over white, 8-bit quantised), no disk.

    `empty` and `plain` are as in `render_sphere`.
    """
    rgb, alpha = render_sphere(cameras, env, empty=empty, plain=plain)
    rgb, alpha = quantize8(rgb), quantize8(alpha)
    over = rgb * alpha[..., None] + (1.0 - alpha[..., None])
    return ViewSet(
        rgb_srgb=torch.from_numpy(over).float(),
        alpha=torch.from_numpy(alpha).float(),
        cameras=cameras,
        names=tuple(f"view{v:03d}" for v in range(cameras.num_views)),
        lighting_index=lighting_index,
    )


def write_sphere_scene(
    root: str | Path,
    *,
    train_views: int = 8,
    test_views: int = 3,
    resolution: int = 64,
    lightings: int = 2,
    empty: bool = False,
) -> SyntheticScene:
    """Write the sphere in gaffer-data's multi-view layout (see the module docstring).

    Lighting k uses `scene_envmap(seed=k)`, written to `root/envmaps/env{k}.exr`. Train and test
    cameras are interleaved orbits; `lit/{VVV}_{LLL}.png` holds view VVV under lighting LLL.
    """
    root = Path(root)
    (root / "lit").mkdir(parents=True, exist_ok=True)
    env_dir = root / "envmaps"
    env_dir.mkdir(exist_ok=True)
    envs = tuple(scene_envmap(seed=k) for k in range(lightings))
    for k, env in enumerate(envs):
        write_envmap(env_dir / f"env{k}.exr", env)
    splits = {
        "train": orbit_cameras(train_views, resolution=resolution),
        "test": orbit_cameras(test_views, resolution=resolution, offset_deg=180.0 / test_views + 7),
    }
    first_index = {"train": 0, "test": train_views}
    f = float(splits["train"].focal_px[0, 0])
    for split, cams in splits.items():
        frames = []
        for k, env in enumerate(envs):
            rgb, alpha = render_sphere(cams, env, empty=empty)
            for v in range(cams.num_views):
                rgba = np.concatenate([rgb[v], alpha[v][..., None]], axis=-1)
                vi = first_index[split] + v
                write_png(root / "lit" / f"{vi:03d}_{k:03d}.png", rgba)
        for v in range(cams.num_views):
            vi = first_index[split] + v
            c2w_blender = cams.c2w_opencv[v].double().numpy() @ BLENDER_TO_OPENCV
            frames.append(
                {
                    "file_path": f"./lit/{vi:03d}_000",
                    "transform_matrix": c2w_blender.tolist(),
                    "view_index": vi,
                    "lit": [
                        {"lighting_index": k, "file_path": f"./lit/{vi:03d}_{k:03d}"}
                        for k in range(lightings)
                    ],
                    "alpha": None,
                }
            )
        body = {
            "camera_angle_x": 2 * math.atan(0.5 * resolution / f),
            "camera_convention": "blender_opengl_c2w",
            "w": resolution,
            "h": resolution,
            "fl_x": f,
            "fl_y": f,
            "cx": resolution / 2.0,
            "cy": resolution / 2.0,
            "lightings": [
                {
                    "lighting_index": k,
                    "envmap": f"env{k}",
                    "flip": False,
                    "yaw_step": 0,
                    "num_steps": 1,
                }
                for k in range(lightings)
            ],
            "frames": frames,
        }
        (root / f"transforms_{split}.json").write_text(json.dumps(body, indent=1))
    return SyntheticScene(
        root=root, envmap_dir=env_dir, envmaps=envs, train_views=train_views, test_views=test_views
    )


def quick_fit_config(**changes: object) -> FitConfig:
    """The tiny preset cut to 120 steps of 512 rays, grid 12^3 -> 24^3 (seconds on one CPU core)."""
    base = dataclasses.replace(
        fit_preset("tiny"),
        iterations=120,
        batch_rays=512,
        initial_voxels=12**3,
        final_voxels=24**3,
        upsample_at=(40, 80),
        alpha_mask_at=(40, 100),
    )
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]
