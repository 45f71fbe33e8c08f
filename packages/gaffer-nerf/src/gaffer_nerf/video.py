"""Orbit videos of a (relit) field: cameras on a circle around the object, PNG frames and a GIF.

A relit radiance field is judged from a video along an orbit around it. `orbit_path` places cameras on a
horizontal circle (world z up) whose radius, elevation and intrinsics follow a reference capture (its
median camera distance and elevation about the centre), starting at the first reference camera's
azimuth; `render_orbit` renders them and writes `frame_000.png`, ... and `orbit.gif`, staged and
renamed into place together (`gaffer_envmap.atomic.atomic_files`), so an interrupted run never leaves
a truncated file, or part of an orbit, under a final name. The PNGs and the GIF are written by
`gaffer_envmap.writers`, gaffer's one writer (its rounding: nearest level, ties to even). GIF only: an
MP4 would need ffmpeg, PyAV or OpenCV, which gaffer-nerf does not depend on.
"""

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor
from tqdm.auto import tqdm

from gaffer_envmap import orbit_w2c_blender
from gaffer_envmap.atomic import atomic_files
from gaffer_envmap.writers import quantize, write_gif, write_png
from gaffer_nerf.cameras import Cameras
from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.evaluate import render_views
from gaffer_nerf.fields.tensorf import TensoRFVM

GIF_NAME = "orbit.gif"


@dataclass(frozen=True, kw_only=True)
class OrbitVideo:
    """What `render_orbit` wrote.

    Attributes:
        frames: the PNG frames, in orbit order.
        gif: the looping animation of those frames.
        fps: its frame rate.
    """

    frames: tuple[Path, ...]
    gif: Path
    fps: float


def orbit_path(
    reference: Cameras,
    num_frames: int,
    *,
    center_world: Sequence[float] | Float[Tensor, " 3"] = (0.0, 0.0, 0.0),
    elevation_deg: float | None = None,
    distance: float | None = None,
) -> Cameras:
    """`num_frames` cameras evenly spaced on a full turn around `center_world`, looking at it.

    Args:
        reference: a capture of the object; the orbit copies its first camera's intrinsics and image
            size, its median distance and elevation about the centre, and its first azimuth.
        num_frames: cameras on the turn (the last one stops one step short of the first).
        center_world: the point looked at (the object's centre; gaffer-data objects sit at the origin).
        elevation_deg: elevation above the horizontal plane through the centre (None: the reference's).
        distance: distance from the centre (None: the reference's).

    Returns:
        `Cameras` with `num_frames` views, azimuth increasing (counter-clockwise seen from above).

    Raises:
        ConfigError: `num_frames` < 1, a non-positive distance, or an elevation outside [-90, 90].

    Example:
        >>> from gaffer_nerf.testing import orbit_cameras
        >>> orbit_path(orbit_cameras(4), 12).num_views
        12
    """
    if num_frames < 1:
        raise ConfigError(f"`num_frames` is {num_frames!r}; expected >= 1.")
    center = torch.as_tensor(center_world, dtype=torch.float64).reshape(-1)
    if center.shape != (3,):
        raise ShapeError("center_world", tuple(center.shape), "[3]")
    offsets = reference.centers_world.to(torch.float64) - center  # [V, 3]
    radii = offsets.norm(dim=1)
    if distance is None:
        distance = float(radii.median())
    if not (math.isfinite(distance) and distance > 0):
        raise ConfigError(
            f"`distance` is {distance!r}; expected > 0 (the reference cameras sit at the centre?)."
        )
    if elevation_deg is None:
        sin_el = (offsets[:, 2] / radii.clamp_min(1e-12)).clamp(-1.0, 1.0)
        elevation_deg = math.degrees(float(torch.asin(sin_el).median()))
    if not -90.0 <= elevation_deg <= 90.0:
        raise ConfigError(f"`elevation_deg` is {elevation_deg!r}; expected a value in [-90, 90].")
    az0 = math.degrees(math.atan2(float(offsets[0, 1]), float(offsets[0, 0])))
    c2w = []
    for k in range(num_frames):
        m = orbit_w2c_blender(az0 + 360.0 * k / num_frames, elevation_deg, distance)
        matrix = m.to_c2w_opencv().matrix.copy()  # [4, 4] about the origin
        matrix[:3, 3] += center.numpy()
        c2w.append(matrix)
    return Cameras(
        c2w_opencv=torch.from_numpy(np.stack(c2w)).float(),
        focal_px=reference.focal_px[:1].float().repeat(num_frames, 1),
        principal_px=reference.principal_px[:1].float().repeat(num_frames, 1),
        width=reference.width,
        height=reference.height,
    )


def render_orbit(
    field: TensoRFVM,
    cameras: Cameras,
    out_dir: str | Path,
    *,
    fps: float = 12.0,
    progress: bool = False,
) -> OrbitVideo:
    """Render one frame per camera into `out_dir` (`frame_000.png`, ...) and loop them as `orbit.gif`.

    Args:
        field: the (relit) field.
        cameras: the path, e.g. from `orbit_path`.
        out_dir: output folder (created).
        fps: GIF frame rate.
        progress: show a progress bar.

    Returns:
        The paths written.

    Raises:
        ConfigError: a non-positive `fps`.
    """
    if not (math.isfinite(fps) and fps > 0):
        raise ConfigError(f"`fps` is {fps!r}; expected > 0.")
    out = Path(out_dir)
    paths: list[Path] = []
    frames: list[np.ndarray] = []
    # the frames and the GIF are staged and renamed into place together: all or none
    with atomic_files(out) as stage:
        for k in tqdm(range(cameras.num_views), disable=not progress, desc="orbit", leave=False):
            frame = quantize(render_views(field, cameras.select([k]))[0].permute(1, 2, 0))
            name = f"frame_{k:03d}.png"
            write_png(stage / name, frame)  # [H, W, 3]
            paths.append(out / name)
            frames.append(frame)
        write_gif(stage / GIF_NAME, frames, fps=fps)
    return OrbitVideo(frames=tuple(paths), gif=out / GIF_NAME, fps=fps)
