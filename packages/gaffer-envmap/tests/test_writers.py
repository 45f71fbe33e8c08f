"""`gaffer_envmap.writers`: the one quantiser (nearest level, ties to even), PNG (8 and 16 bit), GIF
and MP4, each written atomically; the MP4 goes through the encoder this machine has or is refused."""

import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_envmap import writers
from gaffer_envmap.errors import (
    EnvmapWriteError,
    MissingDependencyError,
    NonFiniteError,
    ParameterError,
    ShapeError,
)
from gaffer_envmap.writers import (
    MP4_UNAVAILABLE,
    is_mp4,
    mp4_encoder,
    quantize,
    quantize_float,
    write_animation,
    write_gif,
    write_mp4,
    write_png,
)


def _frames(n: int = 3, h: int = 9, w: int = 7) -> list[np.ndarray]:
    return [np.full((h, w, 3), 40 * k, np.uint8) for k in range(n)]


# ------------------------------------------------------------------------------------------------
# the rounding rule


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_ties_round_to_even_and_half_up_differs_on_even_levels(dtype: type) -> None:
    k = np.arange(255)
    ties = ((k + 0.5) / 255).astype(dtype)
    assert (ties * dtype(255) == k + 0.5).all()  # every one is an exact tie
    got = quantize(ties).astype(int)
    np.testing.assert_array_equal(got, np.where(k % 2 == 0, k, k + 1))
    # gaffer-nerf's former rule, floor(x * 255 + 0.5): one level higher on the ties below even levels
    half_up = np.floor(ties * dtype(255) + dtype(0.5)).astype(int)
    np.testing.assert_array_equal(half_up - got, (k % 2 == 0).astype(int))
    # off the ties both are the nearest level
    near = ((k + 0.3) / 255).astype(dtype)
    np.testing.assert_array_equal(quantize(near), k)


def test_quantize_clips_scales_and_keeps_the_shape() -> None:
    x = np.array([[-0.5, 0.0, 0.25], [0.5, 1.0, 7.0]], np.float32)
    assert quantize(x).tolist() == [[0, 0, 64], [128, 255, 255]]
    assert quantize(x).dtype == np.uint8
    q16 = quantize(x, bits=16)
    assert q16.dtype == np.uint16 and q16.tolist() == [[0, 0, 16384], [32768, 65535, 65535]]
    with pytest.raises(NonFiniteError, match="NaN/Inf"):
        quantize(np.array([0.5, np.nan]))
    with pytest.raises(NonFiniteError):
        quantize(np.array([np.inf]))
    with pytest.raises(ShapeError, match="floats"):
        quantize(np.array([1, 2], np.int64))
    with pytest.raises(ParameterError, match="bits"):
        quantize(x, bits=12)


def test_tensors_quantize_like_arrays_and_quantize_float_stays_a_tensor() -> None:
    t = torch.rand(3, 5, 7) * 1.2 - 0.1
    np.testing.assert_array_equal(quantize(t), quantize(t.numpy()))
    # the rounding torch itself does (what the evaluation scores) is the same rule
    old = (t.clamp(0, 1) * 255.0).round().numpy().astype(np.uint8)
    np.testing.assert_array_equal(quantize(t), old)
    snapped = quantize_float(t)
    assert torch.is_tensor(snapped) and snapped.dtype == t.dtype
    np.testing.assert_array_equal(snapped.numpy() * 255, quantize(t).astype(np.float32))
    arr = quantize_float(t.numpy().astype(np.float64))
    assert arr.dtype == np.float64
    np.testing.assert_array_equal(np.rint(arr * 255), quantize(t))
    with pytest.raises(NonFiniteError):
        quantize_float(torch.tensor([float("nan")]))


def test_half_precision_is_scaled_in_float32() -> None:
    x = torch.linspace(0, 1, 1001)
    want = quantize(x.half().float())  # the half values themselves, rounded without fp16 arithmetic
    np.testing.assert_array_equal(quantize(x.half()), want)
    np.testing.assert_array_equal(quantize(x.half().numpy()), want)
    np.testing.assert_array_equal(quantize(x.bfloat16()), quantize(x.bfloat16().float()))
    assert quantize_float(x.half()).dtype == torch.float16  # a tensor keeps its dtype


# ------------------------------------------------------------------------------------------------
# PNG


@pytest.mark.parametrize("shape", [(5, 7), (5, 7, 1), (5, 7, 2), (5, 7, 3), (5, 7, 4)])
def test_png_8bit_round_trips(tmp_path: Path, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, shape, dtype=np.uint8)
    assert write_png(tmp_path / "a.png", img) == tmp_path / "a.png"
    back = np.asarray(Image.open(tmp_path / "a.png"))
    np.testing.assert_array_equal(back, img[..., 0] if shape[-1:] == (1,) else img)
    x = rng.random(shape).astype(np.float32)
    write_png(tmp_path / "f.png", torch.from_numpy(x))  # a tensor too
    back = np.asarray(Image.open(tmp_path / "f.png"))
    np.testing.assert_array_equal(back, quantize(x)[..., 0] if shape[-1:] == (1,) else quantize(x))


def _read16(path: Path) -> np.ndarray:
    """A 16-bit PNG read by OpenCV (RGB order restored), an independent decoder of ours."""
    cv2 = pytest.importorskip("cv2")
    arr = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert arr is not None and arr.dtype == np.uint16
    if arr.ndim == 3 and arr.shape[2] >= 3:
        order = [2, 1, 0, 3][: arr.shape[2]]
        arr = arr[..., order]
    return arr


@pytest.mark.parametrize("shape", [(6, 5), (6, 5, 3), (6, 5, 4)])
def test_png_16bit_round_trips(tmp_path: Path, shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(1)
    img = rng.integers(0, 65536, shape, dtype=np.uint16)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(_read16(tmp_path / "a.png"), img)
    x = rng.random(shape)
    write_png(tmp_path / "f.png", x, bits=16)
    np.testing.assert_array_equal(_read16(tmp_path / "f.png"), quantize(x, bits=16))


def test_png_16bit_grey_and_grey_alpha_read_by_pillow(tmp_path: Path) -> None:
    grey = np.array([[0, 1, 256], [4095, 40000, 65535]], np.uint16)
    write_png(tmp_path / "g.png", grey)
    with Image.open(tmp_path / "g.png") as im:
        assert im.mode.startswith("I") and np.asarray(im).tolist() == grey.tolist()
    la = np.stack([grey, 65535 - grey], axis=-1)
    write_png(tmp_path / "la.png", la)
    with Image.open(tmp_path / "la.png") as im:  # Pillow reads 16-bit LA at 8 bits: the high bytes
        assert im.size == (3, 2)
        np.testing.assert_array_equal(np.asarray(im.convert("LA")), (la >> 8).astype(np.uint8))


def test_png_refusals(tmp_path: Path) -> None:
    with pytest.raises(ShapeError):
        write_png(tmp_path / "a.png", np.zeros((2, 2, 5), np.uint8))
    with pytest.raises(ShapeError):
        write_png(tmp_path / "a.png", np.zeros((0, 2, 3), np.uint8))
    with pytest.raises(ShapeError, match="uint8, uint16 or floats"):
        write_png(tmp_path / "a.png", np.zeros((2, 2), np.int32))
    with pytest.raises(ShapeError, match="bits=16"):
        write_png(tmp_path / "a.png", np.zeros((2, 2), np.uint8), bits=16)
    with pytest.raises(NonFiniteError):
        write_png(tmp_path / "a.png", np.full((2, 2), np.nan))
    with pytest.raises(EnvmapWriteError, match="does not exist"):
        write_png(tmp_path / "missing" / "a.png", np.zeros((2, 2), np.uint8))
    assert list(tmp_path.iterdir()) == []


def _failing_pillow(monkeypatch: pytest.MonkeyPatch) -> None:
    def save(self: Image.Image, fp: object, *args: object, **kwargs: object) -> None:
        Path(str(fp)).write_bytes(b"\x89PNG\r\n\x1a\n partial")  # some bytes, then the encoder dies
        raise OSError("No space left on device")

    monkeypatch.setattr(Image.Image, "save", save)


@pytest.mark.parametrize("kind", ["png", "png16", "gif"])
def test_a_failure_mid_write_leaves_the_earlier_file_and_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    suffix = "gif" if kind == "gif" else "png"
    old = tmp_path / f"old.{suffix}"
    old.write_bytes(b"an earlier run's file")
    _failing_pillow(monkeypatch)

    def fail16(levels: np.ndarray) -> bytes:
        raise OSError("No space left on device")

    monkeypatch.setattr(writers, "_png16_bytes", fail16)
    for path in (tmp_path / f"new.{suffix}", old):
        with pytest.raises(EnvmapWriteError, match="No space left"):
            if kind == "png":
                write_png(path, np.zeros((4, 4, 3), np.uint8))
            elif kind == "png16":
                write_png(path, np.zeros((4, 4, 3), np.uint16))
            else:
                write_gif(path, _frames(), fps=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == [old.name]
    assert old.read_bytes() == b"an earlier run's file"


def test_writing_needs_no_torch(tmp_path: Path) -> None:
    """gaffer-data's Blender workers have no torch: the writer must not import it."""
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import numpy as np\n"
        "from gaffer_envmap.writers import write_png, write_gif\n"
        f"write_png({str(tmp_path / 'm.png')!r}, np.full((4, 4), 0.5))\n"
        f"write_gif({str(tmp_path / 'a.gif')!r}, [np.zeros((4, 4, 3))] * 2, fps=5)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert np.asarray(Image.open(tmp_path / "m.png")).tolist() == [[128] * 4] * 4


# ------------------------------------------------------------------------------------------------
# GIF


def test_gif_frames_duration_loop_and_white_behind_alpha(tmp_path: Path) -> None:
    frames = _frames(4)
    path = write_gif(tmp_path / "a.gif", frames, fps=10)
    with Image.open(path) as im:
        assert im.n_frames == 4 and im.info["duration"] == 100 and im.info["loop"] == 0
        for k in range(4):  # flat frames survive the palette exactly
            im.seek(k)
            assert np.asarray(im.convert("RGB")).tolist() == frames[k].tolist()
    # GIF keeps 1/100 s, at least 2/100 s: 12 fps plays at 12.5, 100 fps at 50
    assert writers.gif_duration_ms(12) == 83 and writers.gif_duration_ms(100) == 20
    with Image.open(write_gif(tmp_path / "b.gif", frames, fps=100)) as im:
        assert im.info["duration"] == 20
    rgba = np.zeros((4, 4, 4), np.uint8)  # transparent black: white on a GIF
    rgba[:2, :, :3], rgba[:2, :, 3] = 0, 255
    floats = [np.full((4, 4, 3), 0.5, np.float32)] * 2
    with Image.open(write_gif(tmp_path / "c.gif", [rgba, rgba], fps=5)) as im:
        got = np.asarray(im.convert("RGB"))
        assert got[:2].max() == 0 and got[2:].min() == 255
    with Image.open(write_gif(tmp_path / "d.gif", floats, fps=5)) as im:
        assert np.asarray(im.convert("RGB")).max() == 128  # quantised like a PNG


def test_gif_refusals(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="empty"):
        write_gif(tmp_path / "a.gif", [], fps=10)
    with pytest.raises(ParameterError, match="fps"):
        write_gif(tmp_path / "a.gif", _frames(), fps=0)
    with pytest.raises(ParameterError, match="fps"):
        write_gif(tmp_path / "a.gif", _frames(), fps=float("nan"))
    with pytest.raises(ShapeError, match="frames"):
        write_gif(tmp_path / "a.gif", [*_frames(1), np.zeros((9, 8, 3), np.uint8)], fps=10)
    with pytest.raises(ShapeError, match="frames"):
        write_gif(tmp_path / "a.gif", [np.zeros((9, 8), np.uint8)], fps=10)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------------
# MP4


def test_mp4_with_this_machines_encoder_or_a_clear_refusal(tmp_path: Path) -> None:
    frames = _frames(5, 33, 47)  # odd sides on purpose: yuv420p needs even ones, the writer pads
    encoder = mp4_encoder()
    if encoder is None:
        with pytest.raises(MissingDependencyError, match="MP4 needs an encoder"):
            write_mp4(tmp_path / "a.mp4", frames, fps=8)
        assert list(tmp_path.iterdir()) == []
        return
    path = write_mp4(tmp_path / "a.mp4", frames, fps=8)
    assert path == tmp_path / "a.mp4" and is_mp4(path)
    assert [p.name for p in tmp_path.iterdir()] == ["a.mp4"]  # no temporary left
    cv2 = pytest.importorskip("cv2")
    cap = cv2.VideoCapture(str(path))
    count, first = 0, None
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        first = frame if first is None else first
        count += 1
    cap.release()
    assert count == 5 and first is not None and first.shape[:2] == (34, 48)


def test_without_an_encoder_mp4_is_refused_and_auto_writes_a_gif(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))  # no ffmpeg binary
    monkeypatch.setattr(writers, "_opencv_writes_mp4", lambda: False)
    monkeypatch.setattr(writers.importlib.util, "find_spec", lambda name: None)  # nor PyAV
    assert mp4_encoder() is None
    with pytest.raises(MissingDependencyError) as err:
        write_mp4(tmp_path / "a.mp4", _frames(), fps=8)
    assert str(err.value) == MP4_UNAVAILABLE
    with pytest.raises(MissingDependencyError, match="MP4 needs an encoder"):
        write_animation(_frames(), tmp_path / "t", fmt="mp4", fps=8)
    gif = write_animation(_frames(), tmp_path / "t", fmt="auto", fps=8)
    assert gif == tmp_path / "t.gif" and sorted(p.name for p in tmp_path.iterdir()) == ["t.gif"]


def test_auto_takes_h264_only_and_mp4_takes_opencv(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty-bin"))
    monkeypatch.setattr(writers.importlib.util, "find_spec", lambda name: None)
    monkeypatch.setattr(writers, "_opencv_writes_mp4", lambda: True)
    assert mp4_encoder() == "opencv" and mp4_encoder(h264_only=True) is None
    calls: list[str] = []
    monkeypatch.setattr(writers, "_write_opencv", lambda f, p, fps: calls.append(str(p)) or False)
    assert write_animation(_frames(), tmp_path / "t", fmt="auto", fps=8).suffix == ".gif"
    assert calls == []
    with pytest.raises(MissingDependencyError, match="OpenCV wrote no MP4"):
        write_animation(_frames(), tmp_path / "u", fmt="mp4", fps=8)
    assert len(calls) == 1 and not (tmp_path / "u.mp4").exists()


def test_ffmpeg_on_path_gets_the_padded_frames_and_a_failure_leaves_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a stand-in `ffmpeg`: records its arguments and the raw frames, writes a few bytes to its output,
    # then exits with the status in $FAKE_EXIT
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text(
        "#!/bin/sh\n"
        f'echo "$@" > {tmp_path}/args.txt\n'
        f"cat > {tmp_path}/frames.raw\n"
        'for last; do true; done; echo mp4 > "$last"\n'
        'echo "broken pipe" >&2; exit "${FAKE_EXIT:-0}"\n'
    )
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{fake.parent}{os.pathsep}{os.environ['PATH']}")
    out = tmp_path / "out"
    out.mkdir()
    assert mp4_encoder() == "ffmpeg"
    path = write_animation(_frames(), out / "t", fmt="auto", fps=12)
    assert path == out / "t.mp4" and path.read_text().strip() == "mp4"
    args = (tmp_path / "args.txt").read_text()
    assert "-s 8x10" in args and "libx264" in args and "yuv420p" in args and "-r 12" in args
    assert (tmp_path / "frames.raw").stat().st_size == 3 * 10 * 8 * 3
    monkeypatch.setenv("FAKE_EXIT", "1")
    with pytest.raises(MissingDependencyError, match="broken pipe"):
        write_mp4(out / "t.mp4", _frames(), fps=12)
    assert [p.name for p in out.iterdir()] == ["t.mp4"] and path.read_text().strip() == "mp4"
