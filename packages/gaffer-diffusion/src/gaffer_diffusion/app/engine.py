"""What the app does, without Gradio: the library's public calls behind the page's controls.

Each call here mirrors `gaffer-diffusion relight` (cli.py): `load_object_image` crops the object and
puts it on white at the model size, `lighting_from_envmap` rotates the map into the camera frame and
splits it into E_L / E_H (Neural Gaffer §3.2), `RelightPipeline` samples with the model's own
suggested settings (`demo.sampling_for`), and the input's background is kept outside its mask. The
page (`_ui.py`) only turns these results into widgets, so the API and the browser see the same pixels.
"""

import logging
import math
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image

from gaffer_diffusion.app.config import AppConfig, ModelChoice
from gaffer_diffusion.conditioning import (
    CompatMode,
    LightingMaps,
    RelightingConditions,
    lighting_from_envmap,
)
from gaffer_diffusion.demo import LoadedModel, load_model, sampling_for
from gaffer_diffusion.errors import ConfigError, InputValueError
from gaffer_diffusion.loading import load_authors_release
from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig
from gaffer_diffusion.preprocess import PreparedImage, load_object_image

logger = logging.getLogger(__name__)

CAMERA_VIEW_HEIGHT = 128
"""Rows of the camera-frame panorama preview (twice as many columns), enough to see where the sun is."""

BATCH_SIZE = 4
"""Turntable frames per sampling call (as `gaffer-diffusion relight --batch-size`'s default)."""

_ENVMAP_CACHE = 4
"""Environment maps kept decoded, so dragging a slider does not re-read the EXR each time."""


@dataclass(frozen=True, kw_only=True)
class CameraPose:
    """Where the camera orbits and how the light is turned (degrees).

    Attributes:
        azimuth_deg: orbit azimuth, counter-clockwise from world +x seen from above.
        elevation_deg: orbit elevation above the horizon, in [-90, 90].
        spin_deg: extra turn of the light about world up.

    Raises:
        InputValueError: a value is not finite or the elevation is outside [-90, 90].
    """

    azimuth_deg: float = 0.0
    elevation_deg: float = 0.0
    spin_deg: float = 0.0

    def __post_init__(self) -> None:
        for name in ("azimuth_deg", "elevation_deg", "spin_deg"):
            value = getattr(self, name)
            if not isinstance(value, int | float) or not math.isfinite(value):
                raise InputValueError(f"`{name}` is {value!r}; pass a finite number of degrees.")
        if not -90.0 <= self.elevation_deg <= 90.0:
            raise InputValueError(
                f"`elevation_deg` is {self.elevation_deg}; pass a value in [-90, 90]."
            )


@dataclass(frozen=True, kw_only=True)
class LightingPreview:
    """What the model will be conditioned on, as images.

    Attributes:
        ldr: `[S, S, 3]` uint8 E_L, the camera-frame LDR map at the model size.
        hdr: `[S, S, 3]` uint8 E_H, the camera-frame log-normalised HDR map.
        camera_view: `[128, 256, 3]` uint8 tone-mapped camera-frame panorama: u = 0.25 is what
            the camera sees behind the object, u = 0.75 the light from behind the camera.
    """

    ldr: np.ndarray
    hdr: np.ndarray
    camera_view: np.ndarray


@dataclass(frozen=True, kw_only=True)
class RelightResult:
    """A relit photo (one frame) or a turntable (several).

    Attributes:
        input_rgb: `[S, S, 3]` uint8 the model's input: the object cropped, on white.
        mask: `[S, S]` uint8 the object's mask at the model size.
        frames: `[S, S, 3]` uint8 relit images, one per turntable step (one for a plain relight).
        model: the model's label.
        steps: denoising steps used.
    """

    input_rgb: np.ndarray
    mask: np.ndarray
    frames: tuple[np.ndarray, ...]
    model: str
    steps: int


@dataclass(frozen=True, kw_only=True)
class ReadyModel:
    """A picker entry's model, ready to sample.

    Attributes:
        loaded: the networks and their suggested settings.
        pipe: the sampling pipeline on the app's device.
        compat: the lighting encoding the model was trained with.
    """

    loaded: LoadedModel
    pipe: RelightPipeline
    compat: CompatMode

    @property
    def size(self) -> int:
        """The model's square input and output side, pixels."""
        return int(self.loaded.model.config.resolution)


def _uint8(t: torch.Tensor) -> np.ndarray:
    """`[3, H, W]` or `[1, H, W]` float in [0, 1] -> `[H, W, 3]` / `[H, W]` uint8."""
    arr = (t.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255.0).round().astype(np.uint8)
    return arr[..., 0] if arr.shape[-1] == 1 else arr


class Engine:
    """Models, environment maps and relighting for the app; thread-safe, one sampling job at a time.

    Models load on first use and stay loaded (the picker holds a handful at most). The sampling lock
    backs up the Gradio queue's concurrency limit, so the API cannot run two jobs on one model.
    """

    def __init__(self, config: AppConfig) -> None:
        self.config = config
        self._choices = {m.label: m for m in config.models}
        self._models: dict[str, ReadyModel] = {}
        self._envmaps: OrderedDict[tuple[str, float], Any] = OrderedDict()
        self._load_lock = threading.Lock()
        self._sample_lock = threading.Lock()
        self._env_lock = threading.Lock()

    @property
    def model_labels(self) -> list[str]:
        """The picker's entries, the default first."""
        return list(self._choices)

    def model(self, label: str) -> ReadyModel:
        """The model behind a picker entry, loaded once.

        Raises:
            ConfigError: an unknown label.
            CheckpointNotFoundError, CheckpointMismatchError: unusable weights.
        """
        choice = self._choices.get(label)
        if choice is None:
            raise ConfigError(
                f"`model` {label!r} is not in the picker; choose one of {list(self._choices)}."
            )
        with self._load_lock:
            if label not in self._models:
                self._models[label] = self._load(choice)
            return self._models[label]

    def _load(self, choice: ModelChoice) -> ReadyModel:
        if choice.base_model is not None and choice.checkpoint is not None:
            result = load_authors_release(choice.checkpoint, choice.base_model)
            logger.info("%s", result.report.summary())
            loaded = LoadedModel(model=result.model, name=choice.label, source=choice.checkpoint)
        else:
            loaded = load_model(choice.checkpoint, flag="--model")
        pipe = RelightPipeline(loaded.model, RuntimeConfig(device=self.config.device))
        # A model's own encoding (gaffer-tiny: gaffer-envmap's default); others: the authors' (as relight).
        compat: CompatMode = loaded.suggested_compat or "neural-gaffer"
        return ReadyModel(loaded=loaded, pipe=pipe, compat=compat)

    def envmap(self, path: str | Path) -> Any:
        """Read (and cache) an equirectangular `.exr`/`.hdr` map, checking its size.

        Raises:
            gaffer_envmap.errors.GafferEnvmapError: an unreadable file, a map that is not 2:1.
            InputValueError: a map wider than `max_image_side`.
        """
        from gaffer_envmap.io import read_envmap

        p = Path(path)
        key = (str(p), p.stat().st_mtime if p.exists() else 0.0)
        with self._env_lock:
            if key in self._envmaps:
                self._envmaps.move_to_end(key)
                return self._envmaps[key]
        env = read_envmap(p, sanitize="zero")
        if env.width > self.config.max_image_side:
            raise InputValueError(
                f"The environment map is {env.width}x{env.height}; the app takes maps up to "
                f"{self.config.max_image_side} px wide (`--max-image-side`). Downscale it first."
            )
        with self._env_lock:
            self._envmaps[key] = env
            while len(self._envmaps) > _ENVMAP_CACHE:
                self._envmaps.popitem(last=False)
        return env

    def preview(self, label: str, envmap_path: str | Path, pose: CameraPose) -> LightingPreview:
        """E_L, E_H and the camera-frame panorama for the model's size and encoding."""
        from gaffer_envmap.poses import orbit_w2c_blender
        from gaffer_envmap.preview import tonemap_preview
        from gaffer_envmap.rotate import rotate_to_camera

        m = self.model(label)
        env = self.envmap(envmap_path)
        w2c = orbit_w2c_blender(pose.azimuth_deg, pose.elevation_deg)
        maps = lighting_from_envmap(
            env, [w2c], size=m.size, compat=m.compat, spin_deg=pose.spin_deg
        )
        view = rotate_to_camera(
            env, w2c, height=CAMERA_VIEW_HEIGHT, spin_deg=pose.spin_deg, pairing="zip"
        )  # [1, 128, 256, 3] linear radiance
        return LightingPreview(
            ldr=_uint8(maps.ldr[0]),
            hdr=_uint8(maps.hdr[0]),
            camera_view=tonemap_preview(view[0].numpy()),
        )

    def prepare(
        self, label: str, image_path: str | Path, mask_path: str | Path | None
    ) -> PreparedImage:
        """The photo cropped around its object, on white, at the model size.

        Raises:
            InputValueError: an unreadable or too large photo, a photo without alpha and no mask,
                a mask of another size, an empty mask.
        """
        m = self.model(label)
        self._check_image(image_path, "photo")
        if mask_path is None:
            with Image.open(image_path) as im:
                has_alpha = im.mode in ("RGBA", "LA", "PA") or "transparency" in im.info
            if not has_alpha:
                raise InputValueError(
                    "The photo has no alpha channel, so the app cannot tell the object from the "
                    "background: upload a mask (white = object) beside it, or an RGBA PNG whose "
                    "background is transparent."
                )
        else:
            self._check_image(mask_path, "mask")
        fraction = m.loaded.suggested_object_fraction
        kwargs = {} if fraction is None else {"object_fraction": fraction}
        return load_object_image(image_path, mask_path=mask_path, size=m.size, **kwargs)

    def _check_image(self, path: str | Path, what: str) -> None:
        try:
            with Image.open(path) as im:  # reads the header only: no decompression bomb
                w, h = im.size
        except (OSError, ValueError, Image.DecompressionBombError) as exc:
            raise InputValueError(f"Could not read the {what} ({Path(path).name}): {exc}") from exc
        if max(w, h) > self.config.max_image_side:
            raise InputValueError(
                f"The {what} is {w}x{h}; the app takes images up to {self.config.max_image_side} px "
                "on a side (`--max-image-side`). Downscale it first."
            )

    def relight(
        self,
        label: str,
        prepared: PreparedImage,
        envmap_path: str | Path,
        pose: CameraPose,
        *,
        num_inference_steps: int | None = None,
        seed: int = 0,
        frames: int = 0,
    ) -> RelightResult:
        """Relight `prepared` under the map seen from `pose`; `frames` > 1 spins the light a full turn.

        Raises:
            InputValueError: a bad step count or frame count.
        """
        if num_inference_steps is not None and not 1 <= num_inference_steps <= 1000:
            raise InputValueError(
                f"`steps` is {num_inference_steps}; pass 1..1000, or leave it empty."
            )
        if frames < 0 or frames > self.config.max_frames:
            raise InputValueError(
                f"`frames` is {frames}; pass 0..{self.config.max_frames} (`--max-frames`)."
            )
        from gaffer_envmap.poses import orbit_w2c_blender

        m = self.model(label)
        env = self.envmap(envmap_path)
        n = max(frames, 1)
        spin = (
            pose.spin_deg + torch.arange(n, dtype=torch.float64) * (360.0 / n)
            if frames > 1
            else pose.spin_deg
        )
        w2c = orbit_w2c_blender(pose.azimuth_deg, pose.elevation_deg)
        lighting = lighting_from_envmap(env, [w2c] * n, size=m.size, compat=m.compat, spin_deg=spin)
        sampling = sampling_for(m.loaded, num_inference_steps, None)
        out: list[np.ndarray] = []
        with self._sample_lock:
            for lo in range(0, n, BATCH_SIZE):
                hi = min(lo + BATCH_SIZE, n)
                cond = RelightingConditions(
                    image=prepared.image.expand(hi - lo, -1, -1, -1),
                    lighting=LightingMaps(ldr=lighting.ldr[lo:hi], hdr=lighting.hdr[lo:hi]),
                    mask=prepared.mask.expand(hi - lo, -1, -1, -1),
                )
                # one seed for every frame: the light moves, the noise does not (less flicker)
                result = m.pipe(cond, sampling, seeds=[seed] * (hi - lo))
                out.extend(_uint8(img) for img in result.images.cpu())
        return RelightResult(
            input_rgb=_uint8(prepared.image[0]),
            mask=_uint8(prepared.mask[0]),
            frames=tuple(out),
            model=m.loaded.name,
            steps=sampling.num_inference_steps,
        )


def write_gif(path: Path, frames: tuple[np.ndarray, ...] | list[np.ndarray], fps: float) -> Path:
    """An endlessly looping GIF of `[H, W, 3]` uint8 frames (PIL, no ffmpeg needed)."""
    if not frames:
        raise InputValueError("No frames to write: ask for a turntable of 2 or more frames.")
    images = [Image.fromarray(f) for f in frames]
    duration = max(round(1000.0 / fps), 20)
    images[0].save(path, save_all=True, append_images=images[1:], duration=duration, loop=0)
    return path
