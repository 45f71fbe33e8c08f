"""What the app does, without Gradio: the library's public calls behind the page's controls.

Each call here mirrors `gaffer-diffusion relight` (cli/relight.py): `photo.read_photo` reads the photo as it is
displayed, its mask is the uploaded one, its alpha, or `automask.grabcut_mask` (the `--mask auto`
classical fallback), `photo.prepare_photo` crops the object and puts it on white at the model size,
`lighting_from_envmap` rotates the map into the camera frame and splits it into E_L / E_H (Neural Gaffer
§3.2), `RelightPipeline` samples with the model's own suggested settings (`demo.sampling_for`), and
`photo.paste_back` returns the relit object at the photo's full size with detail transfer (pixels
outside the mask are the photo's bytes), or `photo.model_crop` the model-size crop. The page (`_ui.py`)
only turns these results into widgets, so the API and the browser see the same pixels.

`Engine.insert` mirrors `gaffer-diffusion insert` (cli/insert.py) the same way: the object photo
prepared as above, the background read as displayed, `insert_geometry.light_from_photo` (the
background wrapped onto the sphere plus the key light) or a chosen map, `resolve_placement` (checked
before sampling) and `insert.insert_object` (relight, place, pixel-height shadow, composite); the tab's
clicks become its flags in `app.inserting`.
"""

import logging
import math
import threading
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
from PIL import Image

from gaffer_diffusion import images as image_io
from gaffer_diffusion.app.config import AppConfig, ModelChoice
from gaffer_diffusion.app.inserting import InsertOutcome, InsertSettings
from gaffer_diffusion.conditioning import (
    CompatMode,
    lighting_from_envmap,
)
from gaffer_diffusion.demo import LoadedModel, load_model, sampling_for
from gaffer_diffusion.errors import ConfigError, InputValueError, MissingDependencyError
from gaffer_diffusion.insert_geometry import InsertLighting
from gaffer_diffusion.photo import (
    Photo,
    PreparedPhoto,
    check_mask,
    model_crop,
    object_alpha,
    paste_back,
    prepare_photo,
    read_mask,
    read_photo,
    usable_alpha,
)
from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig, relight_in_batches
from gaffer_envmap import writers
from gaffer_envmap.errors import MissingDependencyError as EnvmapMissingDependencyError
from gaffer_envmap.writers import Mp4Encoder
from gaffer_envmap.writers import is_mp4 as is_mp4  # the app's tests and callers ask engine

logger = logging.getLogger(__name__)

CAMERA_VIEW_HEIGHT = 128
"""Rows of the camera-frame panorama preview (twice as many columns), enough to see where the sun is."""

BATCH_SIZE = 4
"""Turntable frames per sampling call (as `gaffer-diffusion relight --batch-size`'s default)."""

_ENVMAP_CACHE = 4

SOURCE_MAP_WIDTH = 512
KEEP_SOURCE_MAPS = 16
"""Maps made from words kept on disk (the newest); an older phrase is made again when asked."""
"""Width of a map made by a lighting source from words (256 rows; the model sees 256 x 256 at most)."""
"""Environment maps kept decoded, so dragging a slider does not re-read the EXR each time."""

OutputSize = Literal["photo", "model"]
"""`photo`: the relit object pasted back into the photo at its full size (default); `model`: the
model's square object crop (`gaffer-diffusion relight --output-size model`)."""

OUTPUT_SIZES: tuple[OutputSize, ...] = ("photo", "model")

AUTO_MASK_NOTE = (
    "Mask estimated by GrabCut (`--mask auto`, a classical fallback, not a learned segmenter): check "
    "it, and upload a corrected mask (white = object) in its place if it is wrong."
)
"""What the page says beside an automatic mask."""


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
        frames: relit images, one per turntable step (one for a plain relight): `[H, W, 3]` uint8 at
            the photo's size (`[H, W, 4]` when the photo has alpha, which is kept), or `[S, S, 3]`
            with `output_size="model"`.
        model: the model's label.
        steps: denoising steps used.
        output_size: "photo" or "model".
    """

    input_rgb: np.ndarray
    mask: np.ndarray
    frames: tuple[np.ndarray, ...]
    model: str
    steps: int
    output_size: OutputSize = "photo"


@dataclass(frozen=True, kw_only=True)
class PhotoInput:
    """A photo ready to relight: framed for the model, with the mask it was framed by.

    Attributes:
        prepared: the photo, its object mask and the model's input (`photo.prepare_photo`).
        mask: `[H, W]` uint8 object mask at the photo's (possibly shrunk) size: the uploaded one,
            the photo's alpha, or the automatic one.
        auto_mask: whether `mask` is the GrabCut estimate.
        shrunk_from: the photo's own `(width, height)` when it was shrunk (turntables), else None.
    """

    prepared: PreparedPhoto
    mask: np.ndarray
    auto_mask: bool = False
    shrunk_from: tuple[int, int] | None = None

    @property
    def size_wh(self) -> tuple[int, int]:
        """`(width, height)` of the photo as relit."""
        return self.prepared.photo.size_wh


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
    arr = image_io.to_uint8(t)
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
        authors = choice.base_model is not None and choice.checkpoint is not None
        loaded = load_model(
            choice.checkpoint,
            flag="--model",
            base_model=choice.base_model if authors else None,
            # the runtime `gaffer-diffusion relight` builds (`--dtype`, default auto)
            runtime=RuntimeConfig(device=self.config.device, dtype=self.config.dtype),
            name=choice.label if authors else None,
        )
        # A model's own encoding (gaffer-tiny: gaffer-envmap's default); others: the authors' (as relight).
        compat: CompatMode = loaded.default_sampling.compat
        return ReadyModel(loaded=loaded, pipe=loaded.pipeline, compat=compat)

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

    def text_sources(self) -> list[str]:
        """Names of the installed lighting sources that start from words (the built-in "sky" and
        plugins of the entry-point group `gaffer.envmap_sources`); broken plugins are left out."""
        from gaffer_envmap.sources import envmap_sources

        return [e.name for e in envmap_sources() if e.source and "text" in e.source.capabilities]

    def source_envmap_path(self, source: str, text: str, folder: Path) -> Path:
        """The map a lighting source makes of `text`, written once into `folder` as an EXR (named by
        a hash of source and words, so the same words reuse it; the newest `KEEP_SOURCE_MAPS` kept)
        and read like an uploaded map.

        Raises:
            InputValueError: no words.
            gaffer_envmap.errors.EnvmapSourceError: an unknown or broken source, a source without
                words, or a map it returned that is not finite, non-negative and 2:1.
        """
        import hashlib

        from gaffer_envmap.io import write_envmap
        from gaffer_envmap.sources import envmap_from_text, load_envmap_source

        words = " ".join(str(text or "").split())
        if not words:
            raise InputValueError(
                f"Lighting source {source!r}: type the words it turns into lighting, e.g. "
                '"golden hour from the left".'
            )
        key = hashlib.sha256(f"{source}\0{words}".encode()).hexdigest()[:24]
        path = Path(folder) / f"source-{key}.exr"
        if not path.exists():
            found = load_envmap_source(source, flag="Lighting source")
            env = envmap_from_text(found, words, width=SOURCE_MAP_WIDTH, flag="Lighting source")
            path.parent.mkdir(parents=True, exist_ok=True)
            write_envmap(path, env)  # atomic: a concurrent reader sees the whole map or none
            made = sorted(
                path.parent.glob("source-*.exr"), key=lambda p: (p == path, p.stat().st_mtime)
            )
            for old in made[:-KEEP_SOURCE_MAPS]:  # bounded disk use, however many phrases come
                old.unlink(missing_ok=True)
        return path

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

    def auto_mask(self, image_path: str | Path) -> np.ndarray:
        """`[H, W]` uint8 GrabCut mask of an uploaded photo (`automask.grabcut_mask`, checked).

        Raises:
            InputValueError: an unreadable or too large photo, or GrabCut found no object.
            MissingDependencyError: OpenCV (the `photo` extra) is not installed.
        """
        self._check_image(image_path, "photo")
        return self._auto_mask(read_photo(image_path))

    @staticmethod
    def _auto_mask(photo: Photo) -> np.ndarray:
        from gaffer_diffusion.automask import grabcut_mask

        try:
            alpha = grabcut_mask(photo.rgb_u8)
        except MissingDependencyError as exc:
            raise MissingDependencyError(
                "The photo has no alpha channel and the automatic mask needs OpenCV, which is not "
                'installed (pip install "gaffer-diffusion[photo]"): upload a mask (white = object).'
            ) from exc
        check_mask(alpha, "The automatic (GrabCut) mask")
        return writers.quantize(alpha)

    def has_alpha(self, image_path: str | Path) -> bool:
        """Whether an uploaded image carries an alpha that marks the object: transparency in its
        header, and not all opaque (`photo.usable_alpha`: an all-opaque alpha gets the automatic
        mask, as in `relight`). A photo over `max_image_side` is not decoded (`prepare` refuses it)."""
        with Image.open(image_path) as im:
            if not (im.mode in ("RGBA", "LA", "PA", "RGBa", "La") or "transparency" in im.info):
                return False
            if max(im.size) > self.config.max_image_side:
                return True
        return usable_alpha(read_photo(image_path)) is not None

    def prepare(
        self,
        label: str,
        image_path: str | Path,
        mask_path: str | Path | None,
        *,
        max_side: int | None = None,
    ) -> PhotoInput:
        """The photo, its mask and the model's input (the object cropped, on white, at the model size).

        The mask is `mask_path`, else the photo's alpha when it marks the object (not all opaque:
        `photo.usable_alpha`), else GrabCut's estimate. `max_side` shrinks a
        larger photo (and its mask) first, so that a turntable's full-size frames stay cheap.

        Raises:
            InputValueError: an unreadable or too large photo, a mask of another size, an empty or
                full mask, GrabCut finding no object.
            MissingDependencyError: no alpha, no mask and no OpenCV for the automatic one.
        """
        m = self.model(label)
        self._check_image(image_path, "photo")
        photo = read_photo(image_path)
        auto = False
        if mask_path is not None:
            self._check_image(mask_path, "mask")
            alpha = object_alpha(photo, read_mask(mask_path, photo))
        elif usable_alpha(photo) is not None:  # an all-opaque alpha marks no object: estimate
            alpha = object_alpha(photo, None)
        else:
            alpha = self._auto_mask(photo).astype(np.float32) / 255.0
            auto = True
        shrunk_from = None
        if max_side is not None and max(photo.size_wh) > max_side:
            shrunk_from = photo.size_wh
            photo, alpha = _shrink(photo, alpha, max_side)
        fraction = m.loaded.default_sampling.object_fraction
        prepared = prepare_photo(
            photo,
            alpha,
            size=m.size,
            compat=m.compat,
            object_fraction=0.75 if fraction is None else fraction,
        )
        mask_u8 = writers.quantize(alpha)
        return PhotoInput(prepared=prepared, mask=mask_u8, auto_mask=auto, shrunk_from=shrunk_from)

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
        if w * h > self.config.max_image_pixels:
            raise InputValueError(
                f"The {what} is {w}x{h} ({w * h / 1e6:.1f} megapixels); the app takes up to "
                f"{self.config.max_megapixels:g} (`--max-image-megapixels`). Downscale it first."
            )

    def relight(
        self,
        label: str,
        photo: PhotoInput,
        envmap_path: str | Path,
        pose: CameraPose,
        *,
        num_inference_steps: int | None = None,
        seed: int = 0,
        frames: int = 0,
        output_size: OutputSize = "photo",
    ) -> RelightResult:
        """Relight `photo` under the map seen from `pose`; `frames` > 1 spins the light a full turn.

        With `output_size="photo"` each result is pasted back into the photo at its size with detail
        transfer (`photo.paste_back`); with "model" it is the model's crop (`photo.model_crop`).

        Raises:
            InputValueError: a bad step count, frame count or output size.
        """
        if output_size not in OUTPUT_SIZES:
            raise InputValueError(
                f"`output_size` is {output_size!r}; pass one of {', '.join(OUTPUT_SIZES)}."
            )
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
        prepared = photo.prepared.model_input
        out: list[np.ndarray] = []
        with self._sample_lock:
            # one seed for every frame: the light moves, the noise does not (less flicker)
            for batch in relight_in_batches(
                m.pipe,
                prepared.image,
                lighting,
                sampling,
                seeds=seed,
                batch_size=BATCH_SIZE,
                mask=prepared.mask,
            ):
                for img in batch.output.images.cpu():
                    if output_size == "model":
                        out.append(model_crop(img))
                    else:
                        out.append(paste_back(photo.prepared, img, detail="transfer"))
        return RelightResult(
            input_rgb=_uint8(prepared.image[0]),
            mask=_uint8(prepared.mask[0]),
            frames=tuple(out),
            model=m.loaded.name,
            steps=sampling.num_inference_steps,
            output_size=output_size,
        )

    def background(self, image_path: str | Path) -> Photo:
        """A background photo for `insert`, checked like every upload (`max_image_side`) and read as
        displayed (EXIF orientation applied, as `insert --into` reads it).

        Raises:
            InputValueError: an unreadable or too large image.
        """
        self._check_image(image_path, "background")
        return read_photo(image_path)

    def insert_lighting(
        self, background: Photo, settings: InsertSettings, envmap_path: str | Path | None = None
    ) -> InsertLighting:
        """The lighting `insert` uses: `--envmap` (a map's path) seen from the level background
        camera, else the map built from the background plus the key light (`--light-from-photo`,
        `insert_geometry.light_from_photo`)."""
        from gaffer_diffusion.insert_geometry import (
            LEVEL_CAMERA,
            BackgroundCamera,
            InsertLighting,
            light_from_photo,
        )

        w, h = background.size_wh
        camera = BackgroundCamera(width=w, height=h, fov_deg=settings.fov_deg, w2c=LEVEL_CAMERA)
        if envmap_path is not None:
            return InsertLighting(
                envmap=self.envmap(envmap_path), camera=camera, source="the chosen map"
            )
        key = settings.key_light
        source = "the background wrapped onto the sphere + " + (
            f"a key light {key.describe()}" if key is not None else "no key light (strength 0)"
        )
        env = light_from_photo(background.rgb, camera, key)
        return InsertLighting(envmap=env, camera=camera, key_light=key, source=source)

    def insert(
        self,
        label: str,
        photo: PhotoInput,
        background: Photo,
        settings: InsertSettings,
        envmap_path: str | Path | None = None,
    ) -> InsertOutcome:
        """`gaffer-diffusion insert`: `photo`'s object relit under the background's lighting (or the
        map at `envmap_path`), placed at `settings.at_xy` with `settings.height_px`, shadowed and
        composited at the background's full size (`gaffer_diffusion.insert.insert_object`).

        The placement is checked before the model samples.

        Raises:
            InputValueError: `at_xy` outside the background, a height that does not fit (the message
                names `--at` / `--height` and the most that fits).
        """
        import time

        from gaffer_diffusion.insert import InsertConfig, insert_object
        from gaffer_diffusion.insert_geometry import object_extent, resolve_placement

        m = self.model(label)
        placement = resolve_placement(
            background.size_wh,
            object_extent(photo.prepared.alpha),
            at_xy=settings.at_xy,
            height_px=settings.height_px,
        )
        lighting = self.insert_lighting(background, settings, envmap_path)
        sampling = sampling_for(m.loaded, settings.num_inference_steps, None)
        config = InsertConfig(
            shadow=settings.shadow, detail="transfer", compat=m.compat, seed=settings.seed
        )
        with self._sample_lock:
            start = time.perf_counter()
            result = insert_object(
                m.pipe,
                sampling,
                prepared=photo.prepared,
                background=background,
                lighting=lighting,
                placement=placement,
                config=config,
            )
            seconds = time.perf_counter() - start
        light = result.light
        return InsertOutcome(
            image=result.image,
            mask=photo.mask,
            placement=placement,
            lighting=lighting.source,
            shadow=(
                f"a 2d shadow from {light.source} ({light.share:.0%} of the ground's light)"
                if settings.shadow == "2d"
                else "no shadow"
            ),
            model=m.loaded.name,
            steps=sampling.num_inference_steps,
            seconds=seconds,
        )


def _shrink(photo: Photo, alpha: np.ndarray, max_side: int) -> tuple[Photo, np.ndarray]:
    """`photo` and its mask resized (Lanczos) so that the longer side is `max_side`."""
    w, h = photo.size_wh
    k = max_side / max(w, h)
    size = (max(round(w * k), 1), max(round(h * k), 1))
    rgb_u8 = np.asarray(Image.fromarray(photo.rgb_u8).resize(size, Image.Resampling.LANCZOS))
    small = Image.fromarray(np.asarray(alpha, np.float32), mode="F")
    alpha_s = np.clip(np.asarray(small.resize(size, Image.Resampling.BILINEAR)), 0.0, 1.0)
    alpha_u8 = None
    if photo.alpha_u8 is not None:
        alpha_u8 = np.asarray(
            Image.fromarray(photo.alpha_u8).resize(size, Image.Resampling.BILINEAR)
        )
    shrunk = Photo(
        rgb_u8=rgb_u8,
        rgb=rgb_u8.astype(np.float32) / 255.0,
        alpha=None if alpha_u8 is None else alpha_u8.astype(np.float32) / 255.0,
        alpha_u8=alpha_u8,
        path=photo.path,
    )
    return shrunk, alpha_s.astype(np.float32)


def write_gif(path: Path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """An endlessly looping GIF of `[H, W, 3|4]` uint8 frames (RGBA over white, as the model's input
    is; Pillow, no ffmpeg needed), written atomically (`gaffer_envmap.writers.write_gif`)."""
    if not frames:
        raise InputValueError("No frames to write: ask for a turntable of 2 or more frames.")
    return writers.write_gif(path, frames, fps=fps)


MP4_UNAVAILABLE = (
    "MP4 needs an encoder and none is installed (an ffmpeg binary on PATH, PyAV: pip install av, or "
    'OpenCV: pip install "gaffer-diffusion[photo]"); the GIF is always available.'
)
"""Why the page has no MP4 download, when it has none."""


def mp4_backend() -> Mp4Encoder | None:
    """The MP4 encoder this machine has offline (`gaffer_envmap.writers.mp4_encoder`: ffmpeg or PyAV,
    H.264, else OpenCV's `mp4v` writer when it can write a probe), or None: the page hides its MP4
    button."""
    return writers.mp4_encoder()


def write_mp4(path: Path, frames: Sequence[np.ndarray], fps: float) -> Path:
    """`[H, W, 3|4]` uint8 frames as an MP4 at `path`, written atomically (`gaffer_envmap.writers`).

    Raises:
        InputValueError: no frames.
        MissingDependencyError: no MP4 encoder (`MP4_UNAVAILABLE`), or the encoder failed.
    """
    if not frames:
        raise InputValueError("No frames to write: ask for a turntable of 2 or more frames.")
    backend = mp4_backend()
    if backend is None:
        raise MissingDependencyError(MP4_UNAVAILABLE)
    try:
        return writers.write_mp4(path, frames, fps=fps, encoder=backend)
    except EnvmapMissingDependencyError as exc:  # the encoder failed: the page offers the GIF
        raise MissingDependencyError(f"{exc} Download the GIF.") from exc
