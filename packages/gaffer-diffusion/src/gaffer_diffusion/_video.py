"""The `relight --turntable` animation: `gaffer_envmap.writers` with the command's `--video` choice.

`--video auto` (the default) writes an H.264 MP4 when an `ffmpeg` binary is on PATH or PyAV is installed
(players and browsers all play it) and a GIF otherwise; OpenCV's MPEG-4 Part 2 writer, which the app
also offers, is not taken here. Nothing is downloaded.
"""

import functools
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from gaffer_diffusion.errors import ConfigError, MissingDependencyError
from gaffer_envmap import writers
from gaffer_envmap.errors import ParameterError
from gaffer_envmap.writers import AnimationFormat as VideoFormat

__all__ = ["NO_MP4", "VideoFormat", "mp4_encoder", "write_animation"]

logger = logging.getLogger(__name__)

mp4_encoder = functools.partial(writers.mp4_encoder, h264_only=True)
"""The H.264 encoder this machine has offline (`ffmpeg` on PATH, then PyAV), or None."""

NO_MP4 = (
    "`--video mp4` needs an MP4 encoder: an `ffmpeg` binary on PATH or PyAV (`pip install av`). "
    'Neither is installed; use `--video gif` (or "auto").'
)


def write_animation(
    frames: Sequence[np.ndarray], stem: Path, *, fmt: VideoFormat = "auto", fps: float | int = 12.0
) -> Path:
    """Write `[H, W, 3]` uint8 frames as `stem.mp4` or `stem.gif`; return the path written.

    Args:
        frames: the frames, all the same shape.
        stem: output path without suffix.
        fmt: "mp4", "gif" or "auto" (MP4 when an H.264 encoder is installed, else GIF, logged).
        fps: frames per second.

    Raises:
        ConfigError: on no frames or a non-positive `fps`.
        MissingDependencyError: `fmt="mp4"` without an encoder (install ffmpeg or PyAV, or use gif).
    """
    encoder = mp4_encoder() if fmt != "gif" else None
    if fmt == "mp4" and encoder is None:
        raise MissingDependencyError(NO_MP4)
    if fmt == "auto" and encoder is None:
        logger.info("no MP4 encoder (ffmpeg on PATH or PyAV) is installed; writing a GIF instead")
    try:
        return writers.write_animation(
            frames, stem, fmt="gif" if encoder is None else "mp4", fps=fps, encoder=encoder
        )
    except ParameterError as exc:  # the command's own error type for its refusals
        raise ConfigError(str(exc)) from exc
