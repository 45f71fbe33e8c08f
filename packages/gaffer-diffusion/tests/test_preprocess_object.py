"""Object-centred square crops: `object_square`, `crop_square`, `load_rgba_on_white`, `read_alpha`."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion.errors import InputValueError
from gaffer_diffusion.preprocess import (
    crop_square,
    load_rgba_on_white,
    object_square,
    prepare_object_image,
    read_alpha,
)


def _alpha(h: int, w: int, rows: slice, cols: slice) -> np.ndarray:
    a = np.zeros((h, w), np.float32)
    a[rows, cols] = 1.0
    return a


@pytest.mark.parametrize(
    ("rows", "cols", "fraction"),
    [
        (slice(10, 30), slice(20, 50), 0.75),  # wider than tall
        (slice(5, 52), slice(30, 41), 0.8),  # taller than wide, odd padding
        (slice(0, 7), slice(0, 5), 0.75),  # at the corner: the square reaches past the image
        (slice(12, 13), slice(40, 41), 1.0),  # one pixel
    ],
)
def test_object_square_centres_the_box_and_sizes_it(rows, cols, fraction) -> None:
    alpha = _alpha(60, 80, rows, cols)
    top, left, side = object_square(alpha, fraction)
    h, w = rows.stop - rows.start, cols.stop - cols.start
    assert side == math.ceil(max(h, w) / fraction)
    # centred to the pixel (exact when side - extent is even)
    assert abs((top + side / 2) - (rows.start + h / 2)) <= 0.5
    assert abs((left + side / 2) - (cols.start + w / 2)) <= 0.5
    assert top <= rows.start and top + side >= rows.stop
    assert left <= cols.start and left + side >= cols.stop
    if (side - h) % 2 == 0:
        assert top + side / 2 == rows.start + h / 2


def test_object_square_example_values_and_errors() -> None:
    alpha = _alpha(60, 80, slice(10, 30), slice(20, 50))
    assert object_square(alpha, 0.75) == (0, 15, 40)  # side ceil(30 / 0.75) = 40
    assert object_square(alpha, 1.0) == (5, 20, 30)
    # soft edges: only alpha above 0.5 is the object, whatever the dtype
    soft = alpha.copy()
    soft[40:45, 60:70] = 0.3
    assert object_square(soft, 0.75) == (0, 15, 40)
    assert object_square(np.round(soft * 255).astype(np.uint8), 0.75) == (0, 15, 40)
    with pytest.raises(InputValueError, match="empty"):
        object_square(np.zeros((8, 8), np.float32), 0.75)
    for bad in (0.0, -0.5, 1.5):
        with pytest.raises(InputValueError, match="object_fraction"):
            object_square(alpha, bad)


def test_object_square_frames_like_prepare_object_image() -> None:
    alpha = _alpha(90, 60, slice(20, 50), slice(10, 40))
    rgb = np.full((90, 60, 3), 0.2, np.float32)
    prep = prepare_object_image(rgb, alpha, size=40, object_fraction=0.75)
    top, left, side = object_square(alpha, 0.75)
    t, lf, b, r = prep.bbox
    assert (b - t, r - lf) == (30, 30)
    assert side == 40  # ceil(30 / 0.75), as prepare_object_image pads to
    crop = crop_square(alpha[..., None], (top, left, side), 0.0)[..., 0]
    np.testing.assert_allclose(crop, prep.mask[0, 0].numpy(), atol=1e-6)  # same size: no resize


def test_crop_square_pads_with_fill_outside_the_image() -> None:
    arr = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    inner = crop_square(arr, (1, 1, 3), -1.0)
    np.testing.assert_array_equal(inner, arr[1:4, 1:4])
    out = crop_square(arr, (-2, -1, 7), -1.0)
    assert out.shape == (7, 7, 3) and out.dtype == arr.dtype
    np.testing.assert_array_equal(out[2:6, 1:6], arr)
    mask = np.ones((7, 7), bool)
    mask[2:6, 1:6] = False
    assert (out[mask] == -1.0).all()
    far = crop_square(arr, (10, 10, 3), 0.5)  # entirely outside: all fill
    assert far.shape == (3, 3, 3) and (far == 0.5).all()
    # past the bottom-right corner
    corner = crop_square(arr, (2, 3, 4), 9.0)
    np.testing.assert_array_equal(corner[:2, :2], arr[2:4, 3:5])
    assert (corner[2:] == 9.0).all() and (corner[:, 2:] == 9.0).all()


def _write_corner_square(path: Path, size: int = 40) -> None:
    """A red opaque 8x8 square at the top-left corner; the transparent rest is green (to show that
    the background really is composited to white)."""
    rgba = np.zeros((size, size, 4), np.uint8)
    rgba[..., 1] = 255
    rgba[2:10, 2:10] = (255, 0, 0, 255)
    Image.fromarray(rgba, "RGBA").save(path)


def test_load_rgba_on_white_with_a_box_centres_the_object(tmp_path: Path) -> None:
    path = tmp_path / "corner.png"
    _write_corner_square(path)
    alpha = read_alpha(path)
    assert alpha.shape == (40, 40) and alpha.dtype == np.float32
    assert alpha[5, 5] == 1.0 and alpha[20, 20] == 0.0
    box = object_square(alpha, 0.5)
    assert box == (-2, -2, 16)
    rgb, a = load_rgba_on_white(path, 32, box=box)
    assert rgb.shape == (3, 32, 32) and a.shape == (1, 32, 32)
    ys, xs = torch.nonzero(a[0] > 0.5, as_tuple=True)
    # the object spans half the side, centred
    assert int(ys.min()) == 8 and int(ys.max()) == 23
    assert int(xs.min()) == 8 and int(xs.max()) == 23
    torch.testing.assert_close(rgb[:, 16, 16], torch.tensor([1.0, 0.0, 0.0]))
    # outside the object (and outside the image): white colour, zero alpha
    torch.testing.assert_close(rgb[:, 0, 0], torch.ones(3))
    torch.testing.assert_close(rgb[:, 31, 31], torch.ones(3))
    assert float(a[0, 0, 0]) == 0.0 and float(a[0, 31, 31]) == 0.0
    # without a box: the whole image, the square stays in its corner
    rgb_w, a_w = load_rgba_on_white(path, 40)
    torch.testing.assert_close(a_w[0], torch.from_numpy(alpha))
    torch.testing.assert_close(rgb_w[:, 5, 5], torch.tensor([1.0, 0.0, 0.0]))
    torch.testing.assert_close(rgb_w[:, 30, 30], torch.ones(3))  # green composited away


def test_load_rgba_on_white_reads_a_separate_mask(tmp_path: Path) -> None:
    rgba_path = tmp_path / "corner.png"
    _write_corner_square(rgba_path)
    rgba = np.asarray(Image.open(rgba_path))
    Image.fromarray(rgba[..., :3], "RGB").save(tmp_path / "rgb.png")
    Image.fromarray(rgba[..., 3], "L").save(tmp_path / "mask.png")
    np.testing.assert_array_equal(read_alpha(tmp_path / "mask.png"), read_alpha(rgba_path))
    box = object_square(read_alpha(tmp_path / "mask.png"), 0.5)
    a = load_rgba_on_white(rgba_path, 32, box=box)
    b = load_rgba_on_white(tmp_path / "rgb.png", 32, alpha_path=tmp_path / "mask.png", box=box)
    torch.testing.assert_close(a[0], b[0])
    torch.testing.assert_close(a[1], b[1])
    Image.fromarray(rgba[:20, :20, 3], "L").save(tmp_path / "small.png")
    with pytest.raises(ValueError, match="size"):
        load_rgba_on_white(tmp_path / "rgb.png", 32, alpha_path=tmp_path / "small.png")
