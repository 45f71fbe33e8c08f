"""`--shadow cycles`: the inserted object's cast shadow from Blender Cycles' shadow catcher.

The paper adds a shadow with a shadow network (Neural Gaffer §4.1, object insertion); here Cycles
renders it physically from a stand-in of the object:

1. **Proxy.** The placed object's mask is inflated into a closed solid standing on the ground: each
   row of the mask (on a grid where the object is at most `PROXY_ROWS` cells tall) is cut into runs,
   and each run becomes a slab whose depth at a column is the half-chord of a circle spanning the run
   (`sqrt(h^2 - (x - c)^2)`): a solid of revolution per run, as the pixel-height shadow assumes
   (`insert_geometry.cast_shadow_2d`), but with the mask's holes and separate parts kept. It stands
   in a vertical plane through the object's foot, square to the camera, at the foot's depth: the
   camera is put 1 unit above the ground and the foot is where its pixel's ray meets the ground, so a
   pixel at the foot is `depth / focal` units wide. An estimated depth map of the object
   (`gaffer-normals` integrated, or any relative depth) can replace the circle's front half.
2. **Scene.** The ground is a large plane through the foot marked as Cycles' shadow catcher; the world
   is the insert's HDR map (`InsertLighting.envmap`: the `--envmap`, or the map built from the photo
   with its key light), the camera the background's (`BackgroundCamera`: field of view and pose).
   The proxy is invisible to the camera and black, so it only takes light away from the ground: its
   cast shadow from every bright part of the map, and the sky it hides near the foot.
3. **Render.** Only the region the shadow can reach is rendered (the object's box and the pixel-height
   shadow's extent, padded), at most `CyclesShadowConfig.size` pixels on its longer side, with
   `samples` samples and OpenImageDenoise. Blender runs in its own process
   (`gaffer_diffusion._cycles_shadow_worker`, as gaffer-data's render workers), so gaffer-diffusion
   needs no bpy unless this mode is used.
4. **Factor.** The Shadow Catcher pass is the factor the background is multiplied by in linear light
   (its luminance: one factor for the three channels, like the 2D shadow). It is resampled to the
   background, faded to 1 over the last `EDGE_FADE` of the rendered region (no seam where the render
   stops), and set to exactly 1 where it darkens by less than `SHADOW_CUTOFF`, so those pixels keep
   their bytes in the composite.
"""

import importlib.util
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from jaxtyping import Float

from gaffer_diffusion import detail_transfer as dt
from gaffer_diffusion.errors import ConfigError, GafferDiffusionError, MissingDependencyError
from gaffer_diffusion.insert_geometry import (
    MIN_FORESHORTENING,
    SHADOW_CUTOFF,
    BackgroundCamera,
    DominantLight,
    InsertLighting,
    PlacedObject,
    cast_shadow_2d,
)
from gaffer_diffusion.preprocess import ALPHA_THRESHOLD
from gaffer_envmap.conventions import row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap

__all__ = [
    "CyclesShadow",
    "CyclesShadowConfig",
    "ProxyScene",
    "ShadowRenderError",
    "bpy_available",
    "cast_shadow_cycles",
    "proxy_albedo",
    "proxy_scene",
    "require_bpy",
    "shadow_region",
]

PROXY_ROWS = 96
"""The proxy is built on a grid where the object is at most this many cells tall."""

EDGE_FADE = 0.08
"""The rendered region's outer fraction (of its shorter side) over which the factor fades to 1."""

REGION_PAD = 0.35
"""Padding of the rendered region around the object and its pixel-height shadow, in object heights."""

LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)
"""Rec. 709 luminance weights (the Shadow Catcher pass's channels -> one factor)."""

WORKER = "gaffer_diffusion._cycles_shadow_worker"
"""The worker module, run as `python -m WORKER`."""

MAX_ALBEDO = 0.9
"""The proxy's albedo is at most this (no real diffuse surface reflects more)."""

FALLBACK = "`--shadow 2d` (the pixel-height shadow, the default)"


class ShadowRenderError(GafferDiffusionError, RuntimeError):
    """The Blender worker failed or timed out; the message has its reason and the fallback."""


def bpy_available() -> bool:
    """Whether Blender's Python module is installed (without importing it: it is large)."""
    return importlib.util.find_spec("bpy") is not None


def require_bpy() -> None:
    """Refuse `--shadow cycles` up front when bpy is missing, naming the fallback.

    Raises:
        MissingDependencyError: bpy is not installed.
    """
    if not bpy_available():
        raise MissingDependencyError(
            "`--shadow cycles` needs Blender's Python module bpy (pip install "
            f'"gaffer-data[render]"), which is not installed; use {FALLBACK}.'
        )


@dataclass(frozen=True, kw_only=True)
class CyclesShadowConfig:
    """How the shadow is rendered.

    Attributes:
        size: the rendered region's longer side, pixels, at most (the shadow is soft: it is resampled
            to the background's resolution).
        samples: Cycles samples per pixel.
        denoise: OpenImageDenoise on the render (when the bpy build has it).
        threads: Cycles threads (0: all cores).
        timeout_s: the worker is killed after this many seconds.
        seed: Cycles' sampling seed.

    Raises:
        ConfigError: a value out of range.
    """

    size: int = 256
    samples: int = 32
    denoise: bool = True
    threads: int = 0
    timeout_s: float = 600.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not (16 <= self.size <= 4096 and 1 <= self.samples <= 65536 and self.threads >= 0):
            raise ConfigError(
                f"CyclesShadowConfig size={self.size}, samples={self.samples}, threads="
                f"{self.threads}: pass size in [16, 4096], samples >= 1 and threads >= 0."
            )
        if not (math.isfinite(self.timeout_s) and self.timeout_s > 0):
            raise ConfigError(f"CyclesShadowConfig timeout_s={self.timeout_s}: pass seconds > 0.")


@dataclass(frozen=True, kw_only=True)
class ProxyScene:
    """The proxy, the ground and the camera in Blender's world (z up; lengths in units where the
    camera stands 1 above the ground unless the foot is at or above the horizon).

    Attributes:
        proxy_verts: `[N, 3]` float64 vertices of the inflated mask.
        proxy_faces: `[M, 4]` int64 quads (closed slabs, one per run of each row).
        ground_verts: `[4, 3]` the ground square, through the foot.
        ground_faces: `[1, 4]`.
        c2w: `[4, 4]` the camera's Blender camera-to-world matrix.
        foot_world: `[3]` the foot on the ground.
        units_per_px: world units per background pixel at the foot's depth.
    """

    proxy_verts: np.ndarray
    proxy_faces: np.ndarray
    ground_verts: np.ndarray
    ground_faces: np.ndarray
    c2w: np.ndarray
    foot_world: np.ndarray
    units_per_px: float


@dataclass(frozen=True, kw_only=True)
class CyclesShadow:
    """What `cast_shadow_cycles` made.

    Attributes:
        factor: `[H, W]` float32 in [0, 1], the background's multiplier (exactly 1: untouched).
        region: `(top, left, bottom, right)` background pixels that were rendered.
        render_wh: `(width, height)` of the rendered region, pixels.
        samples: Cycles samples per pixel.
        denoised: whether OpenImageDenoise was asked for.
        seconds: the worker's wall time (Blender's start included).
    """

    factor: np.ndarray
    region: tuple[int, int, int, int]
    render_wh: tuple[int, int]
    samples: int
    denoised: bool
    seconds: float


def _foot_ray(camera: BackgroundCamera, foot_edge: tuple[float, float]) -> np.ndarray:
    """`[3]` world direction through the foot's pixel, scaled so its component along the camera's
    viewing direction is 1 (so a point `t` along it is `t` deep)."""
    fx, fy = foot_edge
    f = camera.focal_px
    d_cam = np.array([(fx - camera.width / 2.0) / f, -(fy - camera.height / 2.0) / f, -1.0])
    return np.asarray(camera.w2c.rotation, np.float64).T @ d_cam


def _row_runs(inside: np.ndarray) -> list[tuple[int, int]]:
    """`[(start, end)]` (end exclusive) of the True runs of a 1-D mask.

    Example:
        >>> _row_runs(np.array([0, 1, 1, 0, 1], bool))
        [(1, 3), (4, 5)]
    """
    padded = np.concatenate([[False], inside, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def proxy_scene(
    placed: PlacedObject,
    camera: BackgroundCamera,
    relief: Float[np.ndarray, "h w"] | None = None,
) -> ProxyScene:
    """The proxy of `placed`, the ground through its foot and the camera (module docstring).

    Args:
        placed: the object as placed in the background.
        camera: the background camera.
        relief: optional front surface over `placed.alpha`'s grid: how far each pixel stands in front
            of the outline's plane, in background pixels (`insert_relief.ObjectRelief.height`, from
            the estimated normals); the back mirrors it. None: the mask's inflation (round runs).

    Raises:
        ConfigError: the placed object covers no pixel above the alpha threshold, or `relief` is not
            on `placed.alpha`'s grid or not finite.
    """
    rot = np.asarray(camera.w2c.rotation, np.float64)
    cam_pos = np.array([0.0, 0.0, 1.0])
    d = _foot_ray(camera, placed.foot_edge)
    horiz = math.hypot(d[0], d[1])
    # the ray meets the ground 1 below the camera; a foot at or above the horizon is put as far as
    # the 2D shadow assumes (MIN_FORESHORTENING) and the ground raised to it
    t = 1.0 / max(-d[2], MIN_FORESHORTENING * max(horiz, 1e-6))
    foot = cam_pos + t * d
    s = t / camera.focal_px  # world units per pixel at the foot's depth
    right, forward = camera.ground_axes()
    up = np.array([0.0, 0.0, 1.0])
    top, left, _, _ = placed.box
    alpha = np.asarray(placed.alpha, np.float32)
    hb, wb = alpha.shape
    g = max(1.0, placed.height_px / PROXY_ROWS)  # background pixels per cell
    ny, nx = max(math.ceil(hb / g), 1), max(math.ceil(wb / g), 1)
    cy = np.minimum(((np.arange(ny) + 0.5) * g).astype(np.int64), hb - 1)
    cx = np.minimum(((np.arange(nx) + 0.5) * g).astype(np.int64), wb - 1)
    cells = alpha[np.ix_(cy, cx)] > ALPHA_THRESHOLD
    if not cells.any():
        raise ConfigError("The placed object covers no pixel; there is nothing to cast a shadow.")
    rel = None
    if relief is not None:
        rel = np.asarray(relief, np.float64)
        if rel.shape != alpha.shape or not np.isfinite(rel).all():
            raise ConfigError(
                f"The relief is {rel.shape} (finite: {bool(np.isfinite(rel).all())}) but the placed "
                f"object's grid is {alpha.shape}; pass finite heights over `placed.alpha`."
            )
        # sampled at the cells; a corner between two cells of a run gets their mean
        rel = np.maximum(rel[np.ix_(cy, cx)], 0.0) * cells
    rows: list[tuple[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]] = []
    for i in range(ny):
        runs = []
        for a, b in _row_runs(cells[i]):
            xs = left + np.arange(a, b + 1) * g  # cell corners, background pixels
            c, h = left + (a + b) * g / 2.0, (b - a) * g / 2.0
            front = np.sqrt(np.maximum(h**2 - (xs - c) ** 2, 0.0))
            if rel is not None:  # corner k between cells k-1 and k of the run; closed at its ends
                v = rel[i, a:b]
                front = np.concatenate([[0.0], (v[:-1] + v[1:]) / 2.0, [0.0]])
            runs.append((xs, front, front))  # the back mirrors the front
        rows.append((i, runs))
    # The lowest pixel of the object is where its visible surface meets the ground (the foot): the
    # front of the lowest row stands at the foot's depth, the outline's plane that far behind it
    # (a box seen square on stands back by half its width; a ball, whose lowest row is a point, not).
    low = next(r for r in reversed(rows) if r[1])[1]
    setback = max(float(front.max()) for _, front, _ in low)
    verts: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    n = 0
    for i, runs in rows:
        y_top, y_bot = top + i * g, top + min((i + 1) * g, hb)
        for xs, front, back in runs:
            k = len(xs)
            base = foot[None, :] + np.outer((xs - placed.foot_edge[0]) * s, right)
            base = base + setback * s * forward
            for y in (y_top, y_bot):
                lift = (placed.foot_edge[1] - y) * s * up
                verts.append(base + lift - np.outer(front * s, forward))  # front (camera side)
                verts.append(base + lift + np.outer(back * s, forward))  # back
            ft, bk, fb, bb = (n + j * k + np.arange(k) for j in range(4))
            q = np.arange(k - 1)
            faces += [
                np.stack([ft[q], ft[q + 1], fb[q + 1], fb[q]], 1),  # front
                np.stack([bk[q + 1], bk[q], bb[q], bb[q + 1]], 1),  # back
                np.stack([ft[q + 1], ft[q], bk[q], bk[q + 1]], 1),  # top cap
                np.stack([fb[q], fb[q + 1], bb[q + 1], bb[q]], 1),  # bottom cap
            ]
            n += 4 * k
    v = np.concatenate(verts, 0)
    v[:, 2] = np.maximum(v[:, 2], foot[2])  # the lowest cells end on the ground, not under it
    r = 1e3 * max(float(np.linalg.norm(foot - cam_pos)), 1.0)
    ground = foot[None, :] + np.array([[-r, -r, 0.0], [r, -r, 0.0], [r, r, 0.0], [-r, r, 0.0]])
    c2w = np.eye(4)
    c2w[:3, :3] = rot.T
    c2w[:3, 3] = cam_pos
    return ProxyScene(
        proxy_verts=v,
        proxy_faces=np.concatenate(faces, 0).astype(np.int64),
        ground_verts=ground,
        ground_faces=np.array([[0, 1, 2, 3]], np.int64),
        c2w=c2w,
        foot_world=foot,
        units_per_px=s,
    )


def proxy_albedo(placed: PlacedObject, envmap: EnvironmentMap) -> tuple[float, float, float]:
    """The proxy's diffuse albedo (linear RGB): the object's mean linear colour over the map's mean
    radiance, at most `MAX_ALBEDO`.

    Why: the object throws light back onto the ground near it (Blender's truth counts it); a black
    proxy throws none, and its shadow comes out too dark. A diffuse surface of albedo `rho` whose
    normals face every way equally is, on average, `rho` times the mean radiance of the map around it
    (the cosine-weighted irradiance averaged over all normals is `pi` times the mean radiance), so the
    object's mean colour over that mean is the albedo that makes the proxy as bright as the object.
    """
    a = np.asarray(placed.alpha, np.float64)
    lin = dt.srgb_to_linear(np.asarray(placed.rgb, np.float64))
    colour = (lin * a[..., None]).sum((0, 1)) / max(float(a.sum()), 1e-9)
    rad = np.asarray(envmap.radiance_linear, np.float64)[..., :3]
    weights = np.asarray(row_solid_angle(rad.shape[0], rad.shape[1]), np.float64)
    mean = (rad.sum(1) * weights[:, None]).sum(0) / (weights.sum() * rad.shape[1])
    albedo = np.clip(colour / np.maximum(mean, 1e-9), 0.0, MAX_ALBEDO)
    return float(albedo[0]), float(albedo[1]), float(albedo[2])


def shadow_region(
    placed: PlacedObject, camera: BackgroundCamera, light: DominantLight
) -> tuple[int, int, int, int]:
    """`(top, left, bottom, right)`: the background pixels where the shadow is rendered: the object's
    box and the pixel-height shadow of the dominant light, padded by `REGION_PAD` object heights
    (more below and beside the foot, where every light's contact shadow lies), clipped to the frame."""
    t, l, b, r = placed.box
    flat = cast_shadow_2d(placed, camera, light)
    ys, xs = np.nonzero(flat < 1.0)
    if len(ys):
        t, l = min(t, int(ys.min())), min(l, int(xs.min()))
        b, r = max(b, int(ys.max()) + 1), max(r, int(xs.max()) + 1)
    pad = REGION_PAD * placed.height_px
    return (
        max(int(t - pad), 0),
        max(int(l - pad), 0),
        min(math.ceil(b + pad), camera.height),
        min(math.ceil(r + pad), camera.width),
    )


def _render_grid(
    camera: BackgroundCamera, region: tuple[int, int, int, int], size: int
) -> tuple[int, int, tuple[int, int, int, int]]:
    """The full frame's render size `(Rw, Rh)` for which `region` is at most `size` pixels on its
    longer side (never finer than the background), and the region in render pixels."""
    t, l, b, r = region
    q = min(1.0, size / max(b - t, r - l, 1))
    rw, rh = max(round(camera.width * q), 1), max(round(camera.height * q), 1)
    qx, qy = rw / camera.width, rh / camera.height
    rt, rl = math.floor(t * qy), math.floor(l * qx)
    rb, rr = min(math.ceil(b * qy), rh), min(math.ceil(r * qx), rw)
    return rw, rh, (rt, rl, max(rb, rt + 1), max(rr, rl + 1))


def _run_worker(job: dict[str, np.ndarray], config: CyclesShadowConfig) -> tuple[np.ndarray, float]:
    """Run the Blender worker on `job`; returns the Shadow Catcher pass and the seconds it took."""
    threads = config.threads or (os.cpu_count() or 1)
    with tempfile.TemporaryDirectory(prefix="gaffer_shadow_") as tmp:
        job_path, out_path = Path(tmp) / "job.npz", Path(tmp) / "out.npz"
        np.savez(job_path, **job)
        cmd = [sys.executable, "-m", WORKER, "--job", str(job_path), "--out", str(out_path)]
        cmd += ["--threads", str(threads)]
        start = time.perf_counter()
        try:
            proc = subprocess.run(
                cmd, capture_output=True, text=True, timeout=config.timeout_s, check=False
            )
        except subprocess.TimeoutExpired as exc:
            raise ShadowRenderError(
                f"`--shadow cycles`: Blender did not finish in {config.timeout_s:g} s; use "
                f"{FALLBACK}, or fewer samples."
            ) from exc
        seconds = time.perf_counter() - start
        events = [
            json.loads(line[len("GAFFER_EVENT ") :])
            for line in proc.stdout.splitlines()
            if line.startswith("GAFFER_EVENT ")
        ]
        errors = [e for e in events if e.get("event") == "error"]
        if proc.returncode != 0 or not out_path.is_file():
            why = (
                errors[-1]["message"] if errors else (proc.stderr.strip().splitlines() or [""])[-1]
            )
            raise ShadowRenderError(
                f"`--shadow cycles`: the Blender worker failed (exit {proc.returncode}: "
                f"{why or 'no reason given'}); use {FALLBACK}."
            )
        with np.load(out_path) as data:
            return np.asarray(data["shadow"], np.float32), seconds


def _to_background(
    shadow_rgb: np.ndarray,
    camera: BackgroundCamera,
    region: tuple[int, int, int, int],
    grid: tuple[int, int, tuple[int, int, int, int]],
) -> np.ndarray:
    """The rendered pass (render pixels of `grid`'s region) as `[H, W]` factor over the background."""
    rw, rh, (rt, rl, _, _) = grid
    lum = np.clip(np.nan_to_num(shadow_rgb, nan=1.0) @ LUMA, 0.0, 1.0)
    hr, wr = lum.shape
    t, l, b, r = region
    # background pixel centres -> render pixel centres of the crop (bilinear, clamped)
    u = (np.arange(l, r) + 0.5) * rw / camera.width - 0.5 - rl
    v = (np.arange(t, b) + 0.5) * rh / camera.height - 0.5 - rt
    u, v = np.clip(u, 0.0, wr - 1.0), np.clip(v, 0.0, hr - 1.0)
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    u1, v1 = np.minimum(u0 + 1, wr - 1), np.minimum(v0 + 1, hr - 1)
    fu, fv = (u - u0)[None, :], (v - v0)[:, None]
    top = lum[v0][:, u0] * (1 - fu) + lum[v0][:, u1] * fu
    bot = lum[v1][:, u0] * (1 - fu) + lum[v1][:, u1] * fu
    crop = top * (1 - fv) + bot * fv
    # fade to 1 at the region's border, so a shadow cut by it leaves no seam
    fade = max(EDGE_FADE * min(b - t, r - l), 1.0)
    dy = np.minimum(np.arange(b - t) + 0.5, b - t - np.arange(b - t) - 0.5)
    dx = np.minimum(np.arange(r - l) + 0.5, r - l - np.arange(r - l) - 0.5)
    keep = np.clip(np.minimum(dy[:, None], dx[None, :]) / fade, 0.0, 1.0)
    factor = np.ones((camera.height, camera.width), np.float32)
    factor[t:b, l:r] = 1.0 - (1.0 - crop) * keep
    factor[factor > 1.0 - SHADOW_CUTOFF] = 1.0
    return factor


def cast_shadow_cycles(
    placed: PlacedObject,
    lighting: InsertLighting,
    light: DominantLight,
    config: CyclesShadowConfig | None = None,
    *,
    relief: Float[np.ndarray, "h w"] | None = None,
) -> CyclesShadow:
    """The factor the background is multiplied by (linear light) under the object's Cycles shadow.

    Args:
        placed: the object as placed.
        lighting: the insert's lighting: its map lights the scene, its camera sees it.
        light: the dominant light (`dominant_light`): it sets the rendered region only.
        config: render settings (`CyclesShadowConfig`).
        relief: optional front surface of the object over `placed.alpha` (`proxy_scene`); None: the
            mask's inflation.

    Raises:
        MissingDependencyError: bpy is not installed (use `--shadow 2d`).
        ShadowRenderError: the worker failed or timed out.
    """
    config = config or CyclesShadowConfig()
    require_bpy()
    camera = lighting.camera
    scene = proxy_scene(placed, camera, relief)
    region = shadow_region(placed, camera, light)
    grid = _render_grid(camera, region, config.size)
    rw, rh, (rt, rl, rb, rr) = grid
    job = {
        "envmap": np.asarray(lighting.envmap.radiance_linear, np.float32),
        "proxy_verts": scene.proxy_verts,
        "proxy_faces": scene.proxy_faces,
        "proxy_albedo": np.asarray(proxy_albedo(placed, lighting.envmap), np.float64),
        "ground_verts": scene.ground_verts,
        "ground_faces": scene.ground_faces,
        "c2w": scene.c2w,
        "fov_deg": np.float64(camera.fov_deg),
        "resolution": np.array([rw, rh]),
        # Blender's border: fractions of the frame, y from the bottom; nudged into the pixels
        "border": np.array(
            [(rl + 1e-3) / rw, (rr + 1e-3) / rw, (rh - rb + 1e-3) / rh, (rh - rt + 1e-3) / rh]
        ),
        "samples": np.int64(config.samples),
        "denoise": np.bool_(config.denoise),
        "seed": np.int64(config.seed),
    }
    shadow_rgb, seconds = _run_worker(job, config)
    if shadow_rgb.shape != (rb - rt, rr - rl, 3):  # Blender cropped other pixels than asked
        raise ShadowRenderError(
            f"`--shadow cycles`: the worker returned a pass of shape {shadow_rgb.shape}; use "
            f"{FALLBACK}."
        )
    return CyclesShadow(
        factor=_to_background(shadow_rgb, camera, region, grid),
        region=region,
        render_wh=(shadow_rgb.shape[1], shadow_rgb.shape[0]),
        samples=config.samples,
        denoised=config.denoise,
        seconds=seconds,
    )
