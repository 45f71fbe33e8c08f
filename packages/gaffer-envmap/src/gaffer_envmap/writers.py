"""The one image and animation writer of gaffer: quantising, PNG (8 and 16 bit), GIF and MP4.

All four packages write their images through this module, so a float image becomes the same bytes
whichever command saved it:

- `quantize(values, bits=8)`: clip to [0, 1], scale by `2**bits - 1`, round to the nearest level with
  ties to even. `quantize_float` gives the same levels back as floats (a PNG round trip without the
  file: the grid the evaluation scores on).
- `write_png`: `[H, W]` or `[H, W, 1|2|3|4]` as an 8-bit (uint8 or float input) or 16-bit (uint16 input,
  or `bits=16`) PNG.
- `write_gif`, `write_mp4`, `write_animation`: frames as an endlessly looping GIF (Pillow, always
  there) or an MP4 through the encoder this machine has (`mp4_encoder`: an `ffmpeg` binary on PATH,
  PyAV, or OpenCV's writer); nothing is downloaded, and without an encoder the MP4 is refused with
  the reason (`MP4_UNAVAILABLE`).

Why ties to even: it is the rounding `np.rint`, `np.round` and `torch.round` already do (the IEEE 754
default), so a tensor snapped to the grid on the GPU (`quantize_float`) and the PNG saved from it agree
level for level without a custom kernel, and over many ties it has no bias (half up adds half a level
on average to the tied values; truncation takes half a level off every pixel). Values land exactly on a
tie only when `x * 255` is a half-integer, so the choice touches few pixels; gaffer-nerf rounded half up
before (its CHANGELOG says where its saved images may now differ by one level).

Every file is written atomically (`gaffer_envmap.atomic`): a failure mid-write leaves nothing under the
final name and an earlier file there untouched, with an `EnvmapWriteError` (an `OSError`).

Imports numpy only; Pillow, torch, OpenCV and PyAV load when a call needs them, so torch-free processes
(gaffer-data's Blender workers) can write their PNGs here.
"""

import functools
import importlib
import importlib.util
import logging
import math
import os
import shutil
import struct
import subprocess
import tempfile
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, overload

import numpy as np

from gaffer_envmap.atomic import atomic_path
from gaffer_envmap.errors import (
    EnvmapWriteError,
    MissingDependencyError,
    NonFiniteError,
    ParameterError,
    ShapeError,
)

if TYPE_CHECKING:
    import torch

__all__ = [
    "MP4_UNAVAILABLE",
    "AnimationFormat",
    "Mp4Encoder",
    "gif_duration_ms",
    "is_mp4",
    "mp4_encoder",
    "quantize",
    "quantize_float",
    "write_animation",
    "write_gif",
    "write_mp4",
    "write_png",
]

logger = logging.getLogger(__name__)

AnimationFormat = Literal["auto", "gif", "mp4"]
"""`write_animation`'s format: "mp4", "gif" or "auto" (an H.264 MP4 when possible, else a GIF)."""

Mp4Encoder = Literal["ffmpeg", "pyav", "opencv"]
"""An MP4 encoder: an `ffmpeg` binary on PATH or PyAV (both H.264, which every player and browser
plays), or OpenCV's `VideoWriter` (MPEG-4 Part 2, `mp4v`: plays in desktop players, not in browsers)."""

MP4_UNAVAILABLE = (
    "MP4 needs an encoder and none is installed (an `ffmpeg` binary on PATH, PyAV: `pip install av`, "
    "or OpenCV: `pip install opencv-python-headless`); write a GIF instead."
)
"""Why `write_mp4` refuses on a machine without an encoder."""

# ------------------------------------------------------------------------------------------------
# quantising: the one rounding rule


def _levels(bits: int) -> int:
    if bits not in (8, 16):
        raise ParameterError(f"`bits` is {bits!r}; pass 8 or 16.")
    return (1 << bits) - 1


def _is_tensor(values: object) -> bool:
    return type(values).__module__.split(".")[0] == "torch"


def _refuse_non_finite(bad: int) -> None:
    if bad:
        raise NonFiniteError(
            f"`image` holds {bad} NaN/Inf value(s); tone-map and clean it before quantising "
            "(8 and 16-bit images hold values in [0, 1])."
        )


def _as_array(values: "np.ndarray | torch.Tensor") -> np.ndarray:
    """A numpy view or copy of `values`; half-precision floats (which numpy cannot scale to 16 bits
    exactly, and bfloat16 tensors, which numpy cannot hold) become float32 first."""
    if _is_tensor(values):
        t: Any = values
        t = t.detach()
        if t.is_floating_point() and t.element_size() < 4:
            t = t.float()
        return t.cpu().numpy()
    arr = np.asarray(values)
    return arr.astype(np.float32) if arr.dtype == np.float16 else arr


def quantize(values: "np.ndarray | torch.Tensor", bits: int = 8) -> np.ndarray:
    """Floats in [0, 1] -> uint8 (or uint16) levels: clipped, scaled, rounded to nearest, ties to even.

    Args:
        values: a float array or torch tensor of any shape and layout (a tensor is detached and
            copied to the CPU; half precision is scaled in float32); values outside [0, 1] are
            clipped.
        bits: 8 (levels 0..255, uint8) or 16 (0..65535, uint16).

    Returns:
        A numpy array of the same shape.

    Raises:
        ShapeError: integer or boolean input (convert it to floats explicitly).
        NonFiniteError: NaN or Inf.
        ParameterError: `bits` other than 8 or 16.

    Example:
        >>> quantize(np.array([0.0, 0.5, 1.5 / 255, 2.5 / 255, 7.0])).tolist()
        [0, 128, 2, 2, 255]
    """
    top = _levels(bits)
    arr = _as_array(values)
    if not np.issubdtype(arr.dtype, np.floating):
        raise ShapeError(
            "image",
            f"{arr.shape} {arr.dtype}",
            "floats in [0, 1]",
            "Convert integers explicitly (e.g. `(x / 65535).astype(np.float32)`).",
        )
    _refuse_non_finite(int(arr.size - np.count_nonzero(np.isfinite(arr))))
    return np.rint(np.clip(arr, 0.0, 1.0) * float(top)).astype(np.uint8 if bits == 8 else np.uint16)


@overload
def quantize_float(values: np.ndarray, bits: int = 8) -> np.ndarray: ...
@overload
def quantize_float(values: "torch.Tensor", bits: int = 8) -> "torch.Tensor": ...
def quantize_float(
    values: "np.ndarray | torch.Tensor", bits: int = 8
) -> "np.ndarray | torch.Tensor":
    """`quantize`'s levels as floats in [0, 1], same type, dtype and device (what re-reading the PNG gives).

    Example:
        >>> (quantize_float(np.array([0.301, 0.5])) * 255).round(9).tolist()
        [77.0, 128.0]
    """
    top = float(_levels(bits))
    if _is_tensor(values):
        t: Any = values
        _refuse_non_finite(int((~t.isfinite()).sum()))
        return (t.clamp(0.0, 1.0) * top).round() / top
    arr = np.asarray(values)
    _refuse_non_finite(int(arr.size - np.count_nonzero(np.isfinite(arr))))
    return (np.rint(np.clip(arr, 0.0, 1.0) * top) / top).astype(arr.dtype)


# ------------------------------------------------------------------------------------------------
# PNG


def _png_levels(image: "np.ndarray | torch.Tensor", bits: int | None) -> np.ndarray:
    """The stored levels of `image`: uint8 / uint16 as they are, floats through `quantize`."""
    arr = _as_array(image)
    if bits not in (None, 8, 16):
        raise ParameterError(f"`bits` is {bits!r}; pass 8 or 16 (None: from the dtype).")
    if arr.dtype in (np.uint8, np.uint16):
        given = 8 if arr.dtype == np.uint8 else 16
        if bits not in (None, given):
            raise ShapeError(
                "image",
                f"{arr.shape} {arr.dtype}",
                f"{bits}-bit levels for `bits={bits}`",
                "Pass floats in [0, 1] to re-quantise, or leave `bits` out.",
            )
        return arr
    if not np.issubdtype(arr.dtype, np.floating):
        raise ShapeError(
            "image",
            f"{arr.shape} {arr.dtype}",
            "uint8, uint16 or floats in [0, 1]",
            "Convert other integers explicitly (e.g. `(x / 65535).astype(np.float32)`).",
        )
    outside = int(np.count_nonzero((arr < 0) | (arr > 1)))
    if outside:
        logger.info("clipping %d value(s) outside [0, 1] for a PNG", outside)
    return quantize(arr, bits or 8)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _png16_bytes(levels: np.ndarray) -> bytes:
    """A 16-bit PNG (grey, grey + alpha, RGB or RGBA): Pillow writes 16-bit grey only, so the file is
    built here from the PNG specification (big-endian samples, filter type 0 on every row)."""
    h, w = levels.shape[:2]
    channels = 1 if levels.ndim == 2 else levels.shape[2]
    colour_type = {1: 0, 2: 4, 3: 2, 4: 6}[channels]
    rows = np.ascontiguousarray(levels.reshape(h, w * channels).astype(">u2")).view(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()
    header = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + _png_chunk(b"IHDR", header)
        + _png_chunk(b"IDAT", zlib.compress(raw, 6))
        + _png_chunk(b"IEND", b"")
    )


def write_png(
    path: str | os.PathLike[str], image: "np.ndarray | torch.Tensor", *, bits: int | None = None
) -> Path:
    """Write an 8 or 16-bit PNG, atomically; returns `path`.

    Args:
        path: the destination file (its folder must exist).
        image: `[H, W]`, `[H, W, 1]`, `[H, W, 2]` (grey + alpha), `[H, W, 3]` or `[H, W, 4]`
            (channels last; a torch tensor is copied to the CPU): uint8 (an 8-bit PNG, written as
            is), uint16 (a 16-bit PNG, as is) or floats in [0, 1] (clipped, then `quantize`d).
            Values are written as given: encode linear light first.
        bits: the depth of a float image, 8 (default) or 16; for integer input it must match.

    Returns:
        `path`, as a `Path`.

    Raises:
        ShapeError: wrong shape or dtype.
        NonFiniteError: float input with NaN or Inf.
        EnvmapWriteError: the write failed; an existing file at `path` is left untouched.

    Example:
        >>> import tempfile
        >>> p = write_png(tempfile.mkdtemp() + "/a.png", np.array([[[0.0, 0.5, 1.0]]]))
        >>> from PIL import Image
        >>> np.asarray(Image.open(p)).tolist()
        [[[0, 128, 255]]]
    """
    levels = _png_levels(image, bits)
    if levels.ndim == 3 and levels.shape[2] == 1:
        levels = levels[..., 0]
    if (
        levels.ndim not in (2, 3)
        or (levels.ndim == 3 and levels.shape[2] not in (2, 3, 4))
        or 0 in levels.shape
    ):
        raise ShapeError("image", levels.shape, "[H, W], [H, W, 1|2|3|4] with H, W >= 1")
    levels = np.ascontiguousarray(levels)
    with atomic_path(path) as tmp:
        if levels.dtype == np.uint16:
            tmp.write_bytes(_png16_bytes(levels))
        else:
            from PIL import Image

            Image.fromarray(levels).save(tmp, format="PNG")  # mode from the shape: L, LA, RGB, RGBA
    return Path(path)


# ------------------------------------------------------------------------------------------------
# animations: frames


def _check_fps(fps: float | int) -> None:
    try:
        ok = math.isfinite(float(fps)) and float(fps) > 0
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ParameterError(f"`fps` is {fps!r}; expected a frame rate > 0, e.g. 12.")


def _opaque(frame: np.ndarray) -> np.ndarray:
    """An `[H, W, 3]` uint8 frame: RGBA composited over white (GIF and MP4 have no alpha)."""
    if np.issubdtype(frame.dtype, np.floating):
        if frame.shape[2] == 4:
            a = np.clip(frame[..., 3:4], 0.0, 1.0)
            frame = frame[..., :3] * a + (1.0 - a)
        return quantize(frame)
    if frame.dtype != np.uint8:
        raise ShapeError("frames", f"{frame.shape} {frame.dtype}", "uint8 or floats in [0, 1]")
    if frame.shape[2] == 3:
        return frame
    a = frame[..., 3:4].astype(np.float32) / 255.0
    return np.rint(frame[..., :3].astype(np.float32) * a + 255.0 * (1.0 - a)).astype(np.uint8)


def _frames(frames: Sequence[Any]) -> list[np.ndarray]:
    """The frames as `[H, W, 3]` uint8 arrays, after checking there are some, all of one shape."""
    if len(frames) == 0:
        raise ParameterError("`frames` is empty; nothing to animate.")
    arrays = [_as_array(f) for f in frames]
    shape = arrays[0].shape
    for a in arrays:
        if a.shape != shape or a.ndim != 3 or a.shape[2] not in (3, 4) or 0 in a.shape:
            raise ShapeError("frames", a.shape, f"[H, W, 3|4] like the first, {shape}")
    return [_opaque(a) for a in arrays]


def gif_duration_ms(fps: float | int) -> int:
    """A GIF frame's delay for `fps`: GIF stores 1/100 s, and browsers play delays under 2/100 s at
    10 fps, so the delay is at least 20 ms (50 fps at most; 12 fps plays at 12.5).

    Example:
        >>> gif_duration_ms(12), gif_duration_ms(10), gif_duration_ms(120)
        (83, 100, 20)
    """
    _check_fps(fps)
    return max(20, round(1000.0 / fps))


def write_gif(path: str | os.PathLike[str], frames: Sequence[Any], *, fps: float | int) -> Path:
    """An endlessly looping GIF of the frames, `gif_duration_ms(fps)` each, written atomically.

    Every frame is stored whole (disposal 2, no delta optimisation), so no frame depends on the one
    before; Pillow merges identical consecutive frames into one longer frame.

    Args:
        path: the destination `.gif` (its folder must exist).
        frames: `[H, W, 3]` or `[H, W, 4]` (composited over white), uint8 or floats in [0, 1],
            all the same shape.
        fps: frames per second.

    Returns:
        `path`, as a `Path`.

    Raises:
        ParameterError: no frames, or `fps` not > 0.
        ShapeError: a frame of another shape, or not `[H, W, 3|4]`.
        EnvmapWriteError: the write failed; nothing new is left under `path`.
    """
    from PIL import Image

    duration = gif_duration_ms(fps)
    images = [Image.fromarray(f, "RGB") for f in _frames(frames)]
    with atomic_path(path) as tmp:
        images[0].save(
            tmp,
            format="GIF",
            save_all=True,
            append_images=images[1:],
            duration=duration,
            loop=0,
            disposal=2,
            optimize=False,
        )
    return Path(path)


# ------------------------------------------------------------------------------------------------
# MP4: probing the encoders (nothing is downloaded) and writing through one


def is_mp4(path: str | os.PathLike[str]) -> bool:
    """Whether a file starts with an ISO base media `ftyp` box (what every MP4 player looks for)."""
    with open(path, "rb") as f:
        head = f.read(12)
    return len(head) == 12 and head[4:8] == b"ftyp"


def _even(frame: np.ndarray) -> np.ndarray:
    h, w = frame.shape[:2]  # yuv420p needs even sides: repeat the last row / column
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _write_ffmpeg(frames: Sequence[np.ndarray], path: Path, fps: float | int) -> None:
    h, w = frames[0].shape[:2]
    cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24"]
    cmd += ["-s", f"{w}x{h}", "-r", f"{fps:g}", "-i", "-", "-c:v", "libx264"]
    cmd += ["-pix_fmt", "yuv420p", "-crf", "18", "-f", "mp4", str(path)]
    data = b"".join(np.ascontiguousarray(f).tobytes() for f in frames)
    proc = subprocess.run(cmd, input=data, capture_output=True, check=False)
    if proc.returncode != 0:
        raise MissingDependencyError(
            f"ffmpeg could not write `{path}` (exit {proc.returncode}): "
            f"{proc.stderr.decode(errors='replace').strip()}. Write a GIF instead."
        )


def _write_pyav(frames: Sequence[np.ndarray], path: Path, fps: float | int) -> None:
    import fractions

    av: Any = importlib.import_module("av")
    with av.open(str(path), mode="w", format="mp4") as container:
        stream = container.add_stream(
            "libx264", rate=fractions.Fraction(fps).limit_denominator(1000)
        )
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)


def _write_opencv(frames: Sequence[np.ndarray], path: Path, fps: float | int) -> bool:
    """MPEG-4 Part 2 (`mp4v`) through OpenCV's bundled ffmpeg; False when it wrote no MP4."""
    import cv2

    h, w = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"mp4v"), float(fps), (w, h))
    if not writer.isOpened():
        return False
    try:
        for f in frames:
            writer.write(np.ascontiguousarray(f[..., ::-1]))  # OpenCV wants BGR
    finally:
        writer.release()
    return path.is_file() and is_mp4(path)


@functools.cache
def _opencv_writes_mp4() -> bool:
    """Whether OpenCV is installed and its writer can encode a two-frame probe (once a process)."""
    if importlib.util.find_spec("cv2") is None:
        return False
    with tempfile.TemporaryDirectory(prefix="gaffer-mp4-probe-") as tmp:
        probe = [np.zeros((16, 16, 3), np.uint8), np.full((16, 16, 3), 255, np.uint8)]
        try:
            return _write_opencv(probe, Path(tmp) / "probe.mp4", 2.0)
        except Exception:  # a broken OpenCV build: no MP4 from it, the GIF stays
            logger.info("OpenCV cannot write MP4 here", exc_info=True)
            return False


def mp4_encoder(*, h264_only: bool = False) -> Mp4Encoder | None:
    """The MP4 encoder this machine has offline, in order of preference, or None.

    An `ffmpeg` binary on PATH, then PyAV (both H.264), then, unless `h264_only`, OpenCV's `mp4v`
    writer when it can encode a probe (probed once a process). Nothing is installed or downloaded.
    """
    if shutil.which("ffmpeg") is not None:
        return "ffmpeg"
    if importlib.util.find_spec("av") is not None:
        return "pyav"
    if not h264_only and _opencv_writes_mp4():
        return "opencv"
    return None


def write_mp4(
    path: str | os.PathLike[str],
    frames: Sequence[Any],
    *,
    fps: float | int,
    encoder: Mp4Encoder | None = None,
) -> Path:
    """The frames as an MP4 at `path`, written to a sibling and renamed into place (atomic).

    Args:
        path: the destination `.mp4` (its folder must exist).
        frames: as `write_gif`; odd sides are padded by one repeated row / column (yuv420p).
        fps: frames per second.
        encoder: the encoder to use; None: `mp4_encoder()`.

    Returns:
        `path`, as a `Path`.

    Raises:
        ParameterError: no frames, or `fps` not > 0.
        ShapeError: a frame of another shape, or not `[H, W, 3|4]`.
        MissingDependencyError: no encoder (`MP4_UNAVAILABLE`), or the encoder failed.
        EnvmapWriteError: the file could not be written; nothing new is left under `path`.
    """
    _check_fps(fps)
    even = [_even(f) for f in _frames(frames)]
    encoder = encoder or mp4_encoder()
    if encoder is None:
        raise MissingDependencyError(MP4_UNAVAILABLE)
    try:
        with atomic_path(path) as tmp:
            if encoder == "ffmpeg":
                _write_ffmpeg(even, tmp, fps)
            elif encoder == "pyav":
                _write_pyav(even, tmp, fps)
            elif not _write_opencv(even, tmp, fps):
                raise MissingDependencyError(
                    "OpenCV wrote no MP4 (its writer failed); write a GIF."
                )
    except EnvmapWriteError as exc:
        if isinstance(exc.__cause__, MissingDependencyError):  # the encoder's own refusal
            raise exc.__cause__ from None
        raise
    return Path(path)


def write_animation(
    frames: Sequence[Any],
    stem: str | os.PathLike[str],
    *,
    fmt: AnimationFormat = "auto",
    fps: float | int = 12.0,
    encoder: Mp4Encoder | None = None,
) -> Path:
    """The frames as `stem.mp4` or `stem.gif`; returns the path written.

    Args:
        frames: as `write_gif`.
        stem: the output path without its suffix.
        fmt: "mp4" (`encoder`, else any `mp4_encoder()`), "gif", or "auto": an H.264 MP4 when ffmpeg
            or PyAV is installed (or `encoder` is given), else a GIF (logged).
        fps: frames per second.
        encoder: the MP4 encoder to use (see `fmt`).

    Raises:
        ParameterError: no frames, `fps` not > 0, or an unknown `fmt`.
        MissingDependencyError: `fmt="mp4"` without an encoder.
    """
    if fmt not in ("auto", "gif", "mp4"):
        raise ParameterError(f"`fmt` is {fmt!r}; pass 'auto', 'gif' or 'mp4'.")
    _check_fps(fps)
    if fmt != "gif" and encoder is None:
        encoder = mp4_encoder(h264_only=fmt == "auto")
    if fmt == "mp4" or (fmt == "auto" and encoder is not None):
        if encoder is None:
            raise MissingDependencyError(MP4_UNAVAILABLE)
        return write_mp4(Path(stem).with_suffix(".mp4"), frames, fps=fps, encoder=encoder)
    if fmt == "auto":
        logger.info("no MP4 encoder (ffmpeg on PATH or PyAV) is installed; writing a GIF instead")
    return write_gif(Path(stem).with_suffix(".gif"), frames, fps=fps)
