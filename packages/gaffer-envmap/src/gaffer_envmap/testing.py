"""Public test helpers: synthetic maps and plain reference twins of the fast paths.

Siblings and e2e tests import these. The references are written the straightforward way, from the
formulas in ../shared/reference (numpy, float64, loops where clearer), never sharing code with the fast
paths they check.
"""

import math
import os
from pathlib import Path

import numpy as np
import numpy.typing as npt
from PIL import Image

from gaffer_envmap.conventions import direction_grid, row_solid_angle
from gaffer_envmap.environment_map import EnvironmentMap


def disc_sun_map(
    height: int,
    direction: np.ndarray,
    radius_deg: float,
    radiance: float,
    sky: float = 0.0,
    supersample: int = 8,
) -> EnvironmentMap:
    """A Blender-convention map with a disc sun of angular `radius_deg` centred on unit `direction`.

    Pixels on the disc's edge get the covered fraction (from `supersample`^2 sub-samples), so the sun's power
    is radiance * 2pi(1 - cos r) up to the sub-sampling, at any sub-pixel position.
    """
    width = 2 * height
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    s = supersample
    dirs = direction_grid(height * s, width * s)
    inside = (dirs @ d) >= math.cos(math.radians(radius_deg))
    w = row_solid_angle(height * s, width * s)[:, None] * inside
    cov = w.reshape(height, s, width, s).sum((1, 3)) / row_solid_angle(height, width)[:, None]
    rad = sky + radiance * cov
    return EnvironmentMap(radiance_linear=np.repeat(rad[..., None], 3, -1).astype(np.float32))


def smooth_random_map(height: int, seed: int = 0, lobes: int = 6) -> EnvironmentMap:
    """A band-limited positive map: a sum of broad spherical Gaussians (good for inverse/composition tests)."""
    rng = np.random.default_rng(seed)
    dirs = direction_grid(height, 2 * height)
    out = np.full((height, 2 * height, 3), 0.05)
    for _ in range(lobes):
        mu = rng.normal(size=3)
        mu /= np.linalg.norm(mu)
        sharp = rng.uniform(2.0, 6.0)
        color = rng.uniform(0.2, 2.0, size=3)
        out += np.exp(sharp * (dirs @ mu - 1.0))[..., None] * color
    return EnvironmentMap(radiance_linear=out.astype(np.float32))


def reference_neural_gaffer(
    radiance: np.ndarray,
    w2c_blender: np.ndarray,
    size: int = 256,
    *,
    frame: int = 0,
    num_frames: int = 1,
    theta_offset: float = 1e-6,
) -> tuple[np.ndarray, np.ndarray]:
    """The authors' preprocessing written out directly (reference section 4, steps 1-7), one map.

    numpy for the directions, a hand-written align_corners=True zero-padded bilinear lookup, PIL resize.
    `frame` of `num_frames` is their turntable: the row-vector directions are multiplied on the right by
    Rz(-2 pi frame / num_frames) after the camera rotation. `theta_offset` is subtracted from
    arccos(d_z) as they do (docs/encodings.md); 0 gives the reading without it (for tests that must tell
    them apart). Returns uint8 `[size, size, 3]` LDR and HDR.
    """
    he, we, _ = radiance.shape
    theta = np.pi / 2 - (np.arange(he) + 0.5) * np.pi / he
    phi = np.pi - (np.arange(we) + 0.5) * 2 * np.pi / we
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    d_local = np.stack([np.cos(ph) * np.cos(th), np.sin(ph) * np.cos(th), np.sin(th)], -1)
    a = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    ang = -2.0 * np.pi * frame / num_frames
    rz = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1.0]])
    d = d_local @ (a @ np.asarray(w2c_blender, np.float64)[:3, :3]) @ rz
    th2 = np.arccos(np.clip(d[..., 2], -1, 1)) - theta_offset
    ph2 = np.arctan2(d[..., 1], d[..., 0])
    gx = np.clip(-ph2 / np.pi, -(1 - 1e-7), 1 - 1e-7).astype(np.float32)
    gy = np.clip(2 * th2 / np.pi - 1, -(1 - 1e-7), 1 - 1e-7).astype(np.float32)
    rotated = _bilinear_align_corners_zeros(radiance.astype(np.float32), gx, gy)
    ldr = np.clip(rotated, 0, 1) ** np.float32(1 / 2.2)
    log = np.log1p(np.float32(10) * rotated)
    hdr = np.clip(log / log.max(), 0, 1)
    out = []
    for m in (ldr, hdr):
        u8 = np.floor(m * 255).astype(np.uint8)
        out.append(np.asarray(Image.fromarray(u8).resize((size, size), Image.Resampling.BILINEAR)))
    return out[0], out[1]


def _bilinear_align_corners_zeros(img: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """torch.grid_sample(bilinear, zeros, align_corners=True) semantics for one `[H, W, C]` image."""
    h, w, _ = img.shape
    x = (gx.astype(np.float32) + np.float32(1)) / np.float32(2) * np.float32(w - 1)
    y = (gy.astype(np.float32) + np.float32(1)) / np.float32(2) * np.float32(h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    out = np.zeros((*gx.shape, img.shape[2]), np.float32)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xi, yi = x0 + dx, y0 + dy
            ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
            val = np.where(ok[..., None], img[np.clip(yi, 0, h - 1), np.clip(xi, 0, w - 1)], 0)
            out += val * (wx * wy)
    return out


def reference_rotate(
    radiance: np.ndarray, w2c_blender: np.ndarray, height: int, width: int
) -> np.ndarray:
    """Plain numpy twin of `rotate_to_camera(filter="bilinear")`: loops over the four taps, float64."""
    he, we, _ = radiance.shape
    r = np.asarray(w2c_blender, np.float64)[:3, :3]
    u = (np.arange(width) + 0.5) / width
    v = (np.arange(height) + 0.5) / height
    uu, vv = np.meshgrid(u, v)
    th, ph = np.pi * vv, 2 * np.pi * (0.5 - uu)
    # camera frame: up = +y, centre = +x (right), u = 0.25 = -z (forward)
    d_cam = np.stack([np.sin(th) * np.cos(ph), np.cos(th), -np.sin(th) * np.sin(ph)], -1)
    d_world = d_cam @ r
    su = np.mod(0.5 - np.arctan2(d_world[..., 1], d_world[..., 0]) / (2 * np.pi), 1.0)
    sv = np.arccos(np.clip(d_world[..., 2], -1, 1)) / np.pi
    x, y = su * we - 0.5, sv * he - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    out = np.zeros((height, width, 3))
    for dy, wy in ((0, 1 - fy), (1, fy)):
        for dx, wx in ((0, 1 - fx), (1, fx)):
            yi, xi = y0 + dy, x0 + dx
            # across a pole: reflect the row and turn by half
            over = (yi < 0) | (yi >= he)
            yi = np.where(yi < 0, 0, np.where(yi >= he, he - 1, yi))
            xi = np.where(over, xi + we // 2, xi) % we
            out += radiance[yi, xi].astype(np.float64) * wx * wy
    return out


def relative_rms(a: np.ndarray, b: np.ndarray) -> float:
    """sqrt(mean((a - b)^2)) / sqrt(mean(b^2))."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.sqrt(np.mean((a - b) ** 2)) / max(np.sqrt(np.mean(b**2)), 1e-30))


def angle_deg(a: npt.ArrayLike, b: npt.ArrayLike) -> float:
    """Angle between two vectors in degrees."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return math.degrees(math.acos(float(np.clip(c, -1, 1))))


def write_plugin_distribution(
    folder: "str | os.PathLike[str]",
    *,
    name: str,
    entry_points: dict[str, str],
    modules: dict[str, str] | None = None,
    group: str = "gaffer.envmap_sources",
    version: str = "1.0",
) -> Path:
    """Write an installed-looking distribution into `folder` (no pip, no venv: a few milliseconds).

    `folder` gets each `modules` entry as `<module>.py` and a `<name>-<version>.dist-info/` with
    `METADATA` and `entry_points.txt` registering `entry_points` ({entry name: "module:attribute"})
    in `group`. Put `folder` on `sys.path` (pytest: `monkeypatch.syspath_prepend(folder)`) and
    `importlib.metadata` finds the distribution and its entry points, as it would an installed plugin.

    Returns:
        The `*.dist-info` folder.

    Example:
        >>> import importlib.metadata, sys, tempfile
        >>> tmp = tempfile.mkdtemp()
        >>> _ = write_plugin_distribution(tmp, name="demo-plugin", entry_points={"demo": "demo_mod:SOURCE"})
        >>> sys.path.insert(0, tmp)
        >>> [ep.value for ep in importlib.metadata.entry_points(group="gaffer.envmap_sources", name="demo")]
        ['demo_mod:SOURCE']
        >>> sys.path.remove(tmp)
    """
    root = Path(folder)
    root.mkdir(parents=True, exist_ok=True)
    for module, source in (modules or {}).items():
        (root / f"{module}.py").write_text(source)
    dist = root / f"{name.replace('-', '_')}-{version}.dist-info"
    dist.mkdir(exist_ok=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
    lines = [f"[{group}]", *(f"{k} = {v}" for k, v in entry_points.items())]
    (dist / "entry_points.txt").write_text("\n".join(lines) + "\n")
    return dist
