"""Always-on validators for tensors crossing the public API (no `assert`: they raise named errors)."""

import torch

from gaffer_diffusion.errors import InputValueError, ShapeError

RANGE_TOLERANCE = 1e-3
"""Values up to this far outside [0, 1] are clamped (resampling ringing); further out is an error."""


def check_image_batch(argument: str, tensor: torch.Tensor, channels: int = 3) -> None:
    """Raise `ShapeError` unless `tensor` is `[B, channels, H, W]` with B, H, W >= 1."""
    if not isinstance(tensor, torch.Tensor):
        raise ShapeError(argument, type(tensor).__name__, f"a torch.Tensor [B, {channels}, H, W]")
    if tensor.ndim != 4 or tensor.shape[1] != channels or min(tensor.shape) < 1:
        raise ShapeError(
            argument,
            tuple(tensor.shape),
            f"[B, {channels}, H, W] (channels first)",
            "Images are channels-first batches; use `x.permute(0, 3, 1, 2)` for [B, H, W, C] input.",
        )


def check_unit_range(argument: str, tensor: torch.Tensor) -> torch.Tensor:
    """Raise `InputValueError` on NaN/Inf or values outside [0, 1]; return the tensor clamped.

    Values within `RANGE_TOLERANCE` of [0, 1] are clamped silently (bilinear/bicubic overshoot).
    """
    finite = torch.isfinite(tensor)
    if not bool(finite.all()):
        bad = int((~finite).sum())
        raise InputValueError(
            f"`{argument}` holds {bad} NaN/Inf values. Sanitise the input first (for env maps: "
            "`gaffer_envmap` sanitize policies); the model cannot relight undefined pixels."
        )
    lo, hi = float(tensor.min()), float(tensor.max())
    if lo < -RANGE_TOLERANCE or hi > 1 + RANGE_TOLERANCE:
        raise InputValueError(
            f"`{argument}` has values in [{lo:.4g}, {hi:.4g}], expected [0, 1]. Images are sRGB in "
            "[0, 1] (divide 8-bit data by 255); lighting maps must come from "
            "`gaffer_envmap.encode.encode_lighting` (its LDR/HDR maps are in [0, 1])."
        )
    return tensor.clamp(0.0, 1.0)
