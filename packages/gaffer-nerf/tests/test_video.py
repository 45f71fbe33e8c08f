"""Orbit videos: camera path geometry, frames + GIF written atomically, the CLI's `render --orbit`."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_envmap import errors as envmap_errors
from gaffer_envmap.errors import EnvmapWriteError
from gaffer_envmap.writers import write_gif  # gaffer_nerf.write_gif's new home (one writer)
from gaffer_nerf.errors import ConfigError, ShapeError
from gaffer_nerf.fit import FitResult
from gaffer_nerf.testing import orbit_cameras
from gaffer_nerf.video import GIF_NAME, orbit_path, render_orbit


def _project(cams, point: torch.Tensor) -> torch.Tensor:
    """`[V, 2]` pixel coordinates of a world point in every camera."""
    c2w = cams.c2w_opencv.double()
    p_cam = torch.einsum("vji,vj->vi", c2w[:, :3, :3], point.double()[None] - c2w[:, :3, 3])
    return cams.focal_px.double() * p_cam[:, :2] / p_cam[:, 2:] + cams.principal_px.double()


def test_orbit_path_follows_the_reference_capture() -> None:
    ref = orbit_cameras(5, resolution=40, distance=2.5)
    cams = orbit_path(ref, 8)
    assert cams.num_views == 8 and (cams.width, cams.height) == (40, 40)
    torch.testing.assert_close(cams.focal_px, ref.focal_px[:1].repeat(8, 1))
    radii = cams.centers_world.double().norm(dim=1)
    torch.testing.assert_close(radii, torch.full((8,), 2.5, dtype=torch.float64), atol=1e-5, rtol=0)
    z = cams.centers_world[:, 2]
    assert float(z.max() - z.min()) < 1e-5  # one horizontal circle
    # starts at the first reference camera's azimuth and turns evenly, counter-clockwise
    az = torch.atan2(cams.centers_world[:, 1], cams.centers_world[:, 0]).double()
    ref_az = math.atan2(float(ref.centers_world[0, 1]), float(ref.centers_world[0, 0]))
    assert float(az[0]) == pytest.approx(ref_az, abs=1e-5)
    steps = torch.remainder(az.diff(), 2 * math.pi)
    torch.testing.assert_close(steps, torch.full((7,), 2 * math.pi / 8, dtype=torch.float64))
    # every camera looks at the centre: it projects to the principal point
    center = torch.tensor([0.1, -0.2, 0.05])
    off = orbit_path(ref, 6, center_world=center, elevation_deg=30.0, distance=2.0)
    torch.testing.assert_close(_project(off, center), off.principal_px.double(), atol=1e-4, rtol=0)
    rel = off.centers_world.double() - center.double()
    torch.testing.assert_close(rel.norm(dim=1), torch.full((6,), 2.0, dtype=torch.float64))
    assert float(rel[0, 2]) == pytest.approx(2.0 * math.sin(math.radians(30.0)), abs=1e-5)


def test_orbit_path_exceptions() -> None:
    ref = orbit_cameras(2)
    with pytest.raises(ConfigError, match="num_frames"):
        orbit_path(ref, 0)
    with pytest.raises(ConfigError, match="elevation_deg"):
        orbit_path(ref, 3, elevation_deg=120.0)
    with pytest.raises(ConfigError, match="distance"):
        orbit_path(ref, 3, distance=0.0)
    with pytest.raises(ShapeError, match="center_world"):
        orbit_path(ref, 3, center_world=(0.0, 0.0))


def test_render_orbit_writes_frames_and_a_gif(fitted: FitResult, tmp_path: Path) -> None:
    cams = orbit_path(orbit_cameras(4, resolution=24), 4)
    video = render_orbit(fitted.field, cams, tmp_path / "orbit", fps=10.0)
    assert [p.name for p in video.frames] == [f"frame_{k:03d}.png" for k in range(4)]
    assert video.gif == tmp_path / "orbit" / GIF_NAME
    with Image.open(video.gif) as gif:
        assert gif.n_frames == 4 and gif.size == (24, 24) and gif.info["duration"] == 100
    with Image.open(video.frames[0]) as im:
        first = np.asarray(im.convert("RGB"))
    # the sphere sits in the middle of a white frame
    assert first.shape == (24, 24, 3) and first[0, 0].min() > 240 and first[12, 12].min() < 240
    assert sorted(p.name for p in (tmp_path / "orbit").iterdir()) == sorted(
        [GIF_NAME, *(p.name for p in video.frames)]
    )  # no temporaries left behind
    with pytest.raises(ConfigError, match="fps"):
        render_orbit(fitted.field, cams, tmp_path / "x", fps=0.0)


def test_write_gif_is_atomic_and_validates(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "a.gif"
    frames = [np.full((6, 8, 3), v, np.uint8) for v in (0, 120, 250)]
    write_gif(path, frames, fps=10.0)
    before = path.read_bytes()
    with Image.open(path) as gif:
        assert gif.n_frames == 3
    with pytest.raises(envmap_errors.ShapeError, match="frames"):
        write_gif(path, [frames[0], np.zeros((6, 7, 3), np.uint8)], fps=12.0)
    with pytest.raises(envmap_errors.ParameterError, match="empty"):
        write_gif(path, [], fps=12.0)

    def crash(self: Image.Image, fp: Path, *args: object, **kwargs: object) -> None:
        Path(fp).write_bytes(b"GIF89a half")  # a partial file, then the writer dies
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", crash)
    with pytest.raises(EnvmapWriteError, match="disk full"):
        write_gif(path, frames, fps=12.0)
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["a.gif"]
