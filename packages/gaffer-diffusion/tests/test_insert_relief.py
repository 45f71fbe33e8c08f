"""The proxy's relief from estimated normals (`gaffer_diffusion.insert_relief`), for `--shadow cycles`."""

import numpy as np
import torch

from gaffer_diffusion import insert as ins
from gaffer_diffusion import pretrained
from gaffer_diffusion.insert_relief import (
    estimated_relief,
    inflation,
    placed_normals,
    relief_from_normals,
)
from gaffer_diffusion.photo import object_alpha, prepare_photo, read_photo, relit_object

OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"


def _ball(radius: float, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    yy, xx = np.mgrid[0:size, 0:size] + 0.5 - size / 2
    rr = np.hypot(xx, yy)
    mask = rr < radius
    z = np.sqrt(np.maximum(radius**2 - rr**2, 0.0))
    n = np.stack([xx, -yy, z], -1) / radius  # camera frame: y up, rows run down
    n[~mask] = (0.0, 0.0, 1.0)
    return n, mask, z


def test_a_ball_s_normals_integrate_to_the_ball() -> None:
    n, mask, z = _ball(30.0, 70)
    got = relief_from_normals(n, mask)
    assert np.abs(got - z)[mask].mean() < 0.5 and abs(got[35, 35] - 30.0) < 0.5
    assert (got[~mask] == 0).all()


def test_the_normals_shape_what_the_mask_cannot() -> None:
    """A ball and a flat disc have the same mask: the relief tells them apart (the inflation
    cannot); the flat face stands level at about the inflation's mean thickness."""
    n, mask, _ = _ball(20.0, 50)
    flat = np.zeros_like(n)
    flat[..., 2] = 1.0
    ball, disc = relief_from_normals(n, mask), relief_from_normals(flat, mask)
    assert np.ptp(disc[mask]) < 0.2 * np.ptp(ball[mask])
    assert (
        0.5 * inflation(mask)[mask].mean() < disc[mask].mean() < 1.5 * inflation(mask)[mask].mean()
    )
    # a ball tilted toward the right: its highest point moves right
    tilted = n.copy()
    tilted[..., 0] -= 0.3 * mask
    tilted /= np.linalg.norm(tilted, axis=-1, keepdims=True)
    top = np.unravel_index(np.argmax(relief_from_normals(tilted, mask)), mask.shape)
    assert top[1] > 25


def test_the_estimated_relief_lies_on_the_placed_grid() -> None:
    """Over the grid `place_object` gives the relit object (its box: the mask's, padded)."""
    photo = read_photo(OBJECT)
    alpha = object_alpha(photo, None)
    prepared = prepare_photo(photo, alpha, size=128)
    relit = relit_object(prepared, prepared.model_input.image[0], detail="resize")
    assert relit.box != (0, 0, *alpha.shape)  # a box smaller than the photo
    extent = ins.object_extent(alpha)
    placement = ins.resolve_placement((240, 180), extent, at_xy=(120, 150), height_px=60)
    placed = ins.place_object(relit, extent, placement, (180, 240))
    relief = estimated_relief(prepared, relit.box, extent, placement, (180, 240))
    assert relief.height.shape == placed.alpha.shape and relief.source == "gaffer-normals"
    inside = placed.alpha > 0.5
    assert (relief.height[~(placed.alpha > 0)] == 0).all() and relief.height[inside].max() > 3
    assert relief.height.max() < inside.any(0).sum()  # no thicker than the object is wide
    # normals facing the camera stay so, unit length, on the placed grid
    facing = torch.zeros(3, 128, 128)
    facing[2] = 1.0
    n, a = placed_normals(prepared, facing, relit.box, extent, placement, (180, 240))
    assert n.shape[:2] == placed.alpha.shape and np.allclose(a, placed.alpha)
    assert np.allclose(np.linalg.norm(n, axis=-1), 1.0) and np.allclose(n[a > 0.5], (0, 0, 1))
