"""Turntable animations: MP4 through an ffmpeg binary or PyAV when one is installed, otherwise GIF.

Nothing is downloaded: MP4 needs `ffmpeg` on PATH or the `av` package (PyAV) already installed.
"""

import importlib
import importlib.util
import logging
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from gaffer_diffusion.errors import ConfigError, MissingDependencyError

logger = logging.getLogger(__name__)

VideoFormat = Literal["auto", "gif", "mp4"]
"""Animation format: "mp4" (needs an encoder), "gif" (always) or "auto" (MP4 when possible)."""

Mp4Encoder = Literal["ffmpeg", "pyav"]


def mp4_encoder() -> Mp4Encoder | None:
    """The MP4 encoder available offline: an `ffmpeg` binary on PATH, PyAV, or None."""
    if shutil.which("ffmpeg") is not None:
        return "ffmpeg"
    return "pyav" if importlib.util.find_spec("av") is not None else None


def _even(frame: np.ndarray) -> np.ndarray:
    # yuv420p needs even sides; pad the last row / column by repetition
    h, w = frame.shape[:2]
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _write_ffmpeg(frames: Sequence[np.ndarray], path: Path, fps: float | int) -> None:
    h, w = frames[0].shape[:2]
    cmd = ["ffmpeg", "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24"]
    cmd += ["-s", f"{w}x{h}", "-r", f"{fps:g}", "-i", "-", "-c:v", "libx264"]
    cmd += ["-pix_fmt", "yuv420p", "-crf", "18", str(path)]
    data = b"".join(np.ascontiguousarray(f).tobytes() for f in frames)
    proc = subprocess.run(cmd, input=data, capture_output=True, check=False)
    if proc.returncode != 0:
        raise MissingDependencyError(
            f"ffmpeg could not write `{path}` (exit {proc.returncode}): "
            f"{proc.stderr.decode(errors='replace').strip()}. Use `--video gif`."
        )


def _write_pyav(frames: Sequence[np.ndarray], path: Path, fps: float | int) -> None:
    import fractions

    av: Any = importlib.import_module("av")

    with av.open(str(path), mode="w") as container:
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


def write_animation(
    frames: Sequence[np.ndarray], stem: Path, *, fmt: VideoFormat = "auto", fps: float | int = 12.0
) -> Path:
    """Write `[H, W, 3]` uint8 frames as `stem.mp4` or `stem.gif`; return the path written.

    Args:
        frames: the frames, all the same shape.
        stem: output path without suffix.
        fmt: "mp4", "gif" or "auto" (MP4 when an encoder is installed, else GIF, logged).
        fps: frames per second.

    Raises:
        ConfigError: on no frames or a non-positive `fps`.
        MissingDependencyError: `fmt="mp4"` without an encoder (install ffmpeg or PyAV, or use gif).
    """
    if not frames:
        raise ConfigError("`frames` is empty; nothing to animate.")
    if not fps > 0:
        raise ConfigError(f"`fps` is {fps!r}; expected > 0.")
    encoder = mp4_encoder() if fmt in ("auto", "mp4") else None
    if fmt == "mp4" and encoder is None:
        raise MissingDependencyError(
            "`--video mp4` needs an MP4 encoder: an `ffmpeg` binary on PATH or PyAV "
            '(`pip install av`). Neither is installed; use `--video gif` (or "auto").'
        )
    if encoder is not None:
        path = stem.with_suffix(".mp4")
        even = [_even(np.asarray(f, np.uint8)) for f in frames]
        if encoder == "ffmpeg":
            _write_ffmpeg(even, path, fps)
        else:
            _write_pyav(even, path, fps)
        return path
    if fmt == "auto":
        logger.info("no MP4 encoder (ffmpeg on PATH or PyAV) is installed; writing a GIF instead")
    path = stem.with_suffix(".gif")
    from gaffer_diffusion.images import write_gif

    return write_gif(path, frames, round(1000 / fps))
