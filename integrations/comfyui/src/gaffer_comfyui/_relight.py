"""The relighting the nodes share, composed of gaffer-diffusion's public calls exactly as
`gaffer-diffusion relight` composes them (cli/relight.py), so that a node and the command give the same
pixels: `photo.prepare_photo` frames the object for the model, `lighting_from_envmap` turns the map into
the camera frame and splits it into E_L / E_H (Neural Gaffer §3.2), `relight_in_batches` samples with
one seed for every frame (the light moves, the noise does not), and `photo.paste_back` returns the
relit object at the photo's size with detail transfer (pixels outside the mask keep their bytes), or
`photo.model_crop` the model's square crop.
"""

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ._boundary import Progress, library_errors
from ._convert import PhotoItem
from .errors import NodeInputError
from .types import GafferEnvmap, GafferModel

BATCH_SIZE = 4
"""Frames per sampling call (`gaffer-diffusion relight --batch-size`'s default)."""


@dataclass(frozen=True, kw_only=True)
class RelightJob:
    """What one relight or turntable samples (the node's inputs, checked).

    Attributes:
        model: the model.
        envmap: the target lighting.
        pose: `gaffer_envmap.poses.W2CBlender` camera of the photo.
        frames: 1 for a relight; N for a turntable (the light spun by k 360/N degrees at frame k).
        seed: sampling seed (every frame the same).
        sampling: `gaffer_diffusion.pipelines.SamplingConfig`.
        output_size: "input" (the photo's size) or "model" (the model's square crop).
        detail: "transfer" or "resize" (how the result reaches the photo's size).
        background: "input" (the photo's pixels around the object) or "envmap" (the target map as
            the camera sees it).
    """

    model: GafferModel
    envmap: GafferEnvmap
    pose: Any
    frames: int
    seed: int
    sampling: Any
    output_size: str
    detail: str
    background: str


@dataclass(frozen=True, kw_only=True)
class Relit:
    """One picture relit: `frames` uint8 `[H, W, 3]` (one per turntable step) and the object mask
    `[H, W]` (1 on the object) at their size."""

    frames: list[np.ndarray]
    alpha: np.ndarray


def relight_item(node: str, job: RelightJob, item: PhotoItem, progress: Progress) -> Relit:
    """Relight one picture under `job` (every frame), as `gaffer-diffusion relight` does."""
    import torch

    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import relight_in_batches

    model = job.model
    with library_errors(node, "`image` / `mask`"):
        prepared = prepare_photo(item.photo, item.alpha, size=model.size, compat=model.compat)  # type: ignore[arg-type]
    n = job.frames
    # as `relight --turntable N`: frame k spins the light by k 360/N degrees about world up
    spin: Any = torch.arange(n, dtype=torch.float64) * (360.0 / n) if n > 1 else 0.0
    with library_errors(node, "`envmap`"):
        lighting = lighting_from_envmap(
            job.envmap.envmap, [job.pose] * n, size=model.size, compat=model.compat, spin_deg=spin
        )
    frames: list[np.ndarray] = []
    model_in = prepared.model_input
    with torch.no_grad():
        for batch in relight_in_batches(
            model.pipe,
            model_in.image,
            lighting,
            job.sampling,
            seeds=job.seed,
            batch_size=BATCH_SIZE,
            mask=model_in.mask,
        ):
            for j, relit in enumerate(batch.output.images.float().cpu()):
                frames.append(_finish(job, prepared, relit, batch.start + j))
            progress.update(batch.stop - batch.start)
    if job.output_size == "model":
        alpha = model_in.mask[0, 0].numpy().astype(np.float32)
    else:
        alpha = np.asarray(item.alpha, np.float32)
    return Relit(frames=frames, alpha=alpha)


def _finish(job: RelightJob, prepared: Any, relit: Any, k: int) -> np.ndarray:
    """One model result as `gaffer-diffusion relight` writes it (cli/_photo.py `_finish`)."""
    from gaffer_diffusion.photo import model_crop, paste_back

    match job.output_size:
        case "model":
            s = int(relit.shape[-1])
            # the crop sees a narrower field than the photo: its share of the photo's width
            share = prepared.framing.side_x / prepared.photo.size_wh[0]
            fov = float(np.rad2deg(2 * np.arctan(np.tan(np.deg2rad(_fov()) / 2) * share)))
            bd = _backdrop(job, s, s, min(fov, 179.0), k)
            if bd is None:
                return model_crop(relit)
            m = prepared.model_input.mask[0, 0].numpy()[..., None]
            rgb = relit.clamp(0, 1).permute(1, 2, 0).numpy()
            return np.round((m * rgb + (1 - m) * bd) * 255).astype(np.uint8)
        case "input":
            h, w = prepared.alpha.shape
            bd = _backdrop(job, h, w, _fov(), k)
            out = paste_back(prepared, relit, detail=job.detail, backdrop=bd)  # type: ignore[arg-type]
            return np.ascontiguousarray(out[..., :3])
        case _:
            raise NodeInputError(f"`output_size` is {job.output_size!r}; choose input or model.")


def _fov() -> float:
    from gaffer_diffusion.photo import BACKDROP_FOV_DEG

    return float(BACKDROP_FOV_DEG)


def _backdrop(job: RelightJob, height: int, width: int, fov: float, k: int) -> np.ndarray | None:
    """The target map as the photo's camera sees it (`background` "envmap"), else None."""
    if job.background != "envmap":
        return None
    from gaffer_diffusion.photo import envmap_backdrop

    env = job.envmap.envmap
    return envmap_backdrop(
        env.radiance_linear,
        job.pose.rotation,
        height=height,
        width=width,
        convention=env.convention,
        fov_deg=fov,
        spin_deg=k * 360.0 / job.frames if job.frames > 1 else 0.0,
    )


def camera_pose(node: str, azimuth: float, elevation: float, w2c: str) -> Any:
    """The photo's camera: `w2c` when given (12 or 16 numbers, row-major, or a `.npy` path), else
    the orbit camera at (`azimuth`, `elevation`) (`gaffer_envmap.poses.orbit_w2c_blender`).

    Raises:
        NodeInputError: angles out of range, or a `w2c` that is not a 3x4 / 4x4 rigid pose.
    """
    from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender

    text = str(w2c or "").strip()
    if text:
        with library_errors(node, "`w2c`"):
            return W2CBlender.from_array(_read_w2c(node, text))
    check_number(node, "azimuth", azimuth, -360.0, 360.0)
    check_number(node, "elevation", elevation, -90.0, 90.0)
    return orbit_w2c_blender(float(azimuth), float(elevation))


def _read_w2c(node: str, text: str) -> np.ndarray:
    if text.lower().endswith(".npy"):
        path = Path(text).expanduser()
        if not path.is_file():
            raise NodeInputError(f"{node}: `w2c` {text!r} is not an existing .npy file.")
        try:
            arr = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise NodeInputError(
                f"{node}: `w2c` {path.name} is not a plain numeric .npy ({exc}); save the matrix "
                "with numpy.save."
            ) from exc
    else:
        parts = [p for p in re.split(r"[\s,;\[\]()]+", text) if p]
        try:
            arr = np.array([float(p) for p in parts])
        except ValueError as exc:
            raise NodeInputError(
                f"{node}: `w2c` {text[:60]!r} is neither numbers nor a .npy path; give the 12 (3x4) "
                "or 16 (4x4) numbers of a Blender world-to-camera matrix, row by row."
            ) from exc
        if arr.size not in (12, 16):
            raise NodeInputError(
                f"{node}: `w2c` holds {arr.size} numbers; give 12 (3x4) or 16 (4x4), row by row."
            )
        arr = arr.reshape(3 if arr.size == 12 else 4, 4)
    if arr.dtype.kind not in "fiu" or arr.shape not in ((3, 4), (4, 4)):
        raise NodeInputError(
            f"{node}: `w2c` has shape {arr.shape}; give a 3x4 or 4x4 world-to-camera matrix."
        )
    if not np.isfinite(arr).all():
        raise NodeInputError(f"{node}: `w2c` holds NaN or Inf; give a finite matrix.")
    return arr.astype(np.float64)


def check_number(node: str, name: str, value: object, lo: float, hi: float) -> float:
    """`value` as a float in [lo, hi], else a one-line refusal naming `name`."""
    if (
        isinstance(value, bool)
        or not isinstance(value, int | float)
        or not math.isfinite(value)
        or not lo <= value <= hi
    ):
        raise NodeInputError(f"{node}: `{name}` is {value!r}; pass a number in [{lo:g}, {hi:g}].")
    return float(value)


def check_choice(node: str, name: str, value: object, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise NodeInputError(f"{node}: `{name}` is {value!r}; choose one of {list(choices)}.")
    return str(value)


def check_model(node: str, model: object) -> GafferModel:
    if not isinstance(model, GafferModel):
        raise NodeInputError(
            f"{node}: `model` is a {type(model).__name__}; connect NeuralGafferLoadModel's output."
        )
    return model


def check_envmap(node: str, envmap: object) -> GafferEnvmap:
    if not isinstance(envmap, GafferEnvmap):
        raise NodeInputError(
            f"{node}: `envmap` is a {type(envmap).__name__}; connect a GAFFER_ENVMAP (from "
            "NeuralGafferLoadEnvmap, NeuralGafferSky or NeuralGafferRotateEnvmap)."
        )
    return envmap


def sampling_for(
    node: str, model: GafferModel, steps: object, guidance: object, seed: object
) -> Any:
    """The model's `SamplingConfig` with `steps` / `guidance` overrides, checked (the seed too)."""
    if isinstance(steps, bool) or not isinstance(steps, int) or not 0 <= steps <= 1000:
        raise NodeInputError(
            f"{node}: `steps` is {steps!r}; pass 0 (the model's own) or 1..1000 denoising steps."
        )
    check_number(node, "guidance", guidance, -1.0, 100.0)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise NodeInputError(f"{node}: `seed` is {seed!r}; pass an integer in [0, 2**63).")
    with library_errors(node, "`steps` / `guidance`"):
        return model.sampling(int(steps), float(guidance))  # type: ignore[arg-type]
