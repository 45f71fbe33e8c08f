"""The typed requests of `relight`, `evaluate` and `insert`: what a command is asked to do, built once
from its parsed arguments by `cli._from_args` (which performs every refusal), so the command bodies
read no `argparse.Namespace`.

Each file a request names is read there, once: the photo and its mask (`PhotoMask`), the environment
map(s) (`EnvmapLight.env`), the camera of `--w2c` (`EnvmapLight.pose`) and the model folder's own
sampling (`ModelChoice.sampling`). The frozen dataclasses here import no torch; the methods that build
torch objects (`EnvmapLight.maps`, `ModelChoice.runtime_config`, ...) import it when called.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion._choices import Background, DetailMode, OutputSize, ShadowMode
from gaffer_diffusion.cli._common import _device_name, _save_png
from gaffer_diffusion.suggested import DefaultSampling, LatentModeName

if TYPE_CHECKING:
    import numpy as np

    from gaffer_diffusion.conditioning import LightingMaps
    from gaffer_diffusion.evaluation.records import EvalPair
    from gaffer_diffusion.insert_geometry import InsertLighting, Placement
    from gaffer_diffusion.photo import Photo
    from gaffer_diffusion.pipelines import RuntimeConfig, SamplingConfig
    from gaffer_envmap import EnvironmentMap
    from gaffer_envmap.poses import W2CBlender

__all__ = [
    "EncodedLight",
    "EnvmapLight",
    "EvaluateDatasetRequest",
    "EvaluateFoldersRequest",
    "EvaluateRequest",
    "InsertRequest",
    "Light",
    "ModelChoice",
    "OutputLook",
    "PhotoMask",
    "RelightRequest",
    "Reports",
    "RuntimeChoice",
]


@dataclass(frozen=True, kw_only=True)
class PhotoMask:
    """A photo read for a command, with its object mask.

    Attributes:
        photo: the photo.
        alpha: `[H, W]` float32 object mask in [0, 1].
        note: what the report says about an estimated mask ("" for a given one or the alpha).
        estimated: `[H, W]` uint8 estimated mask to write at `mask_out` together with the outputs
            (complete or absent with them: `write_with_outputs`), or None.
        mask_out: where an estimated mask goes (`OUT.mask.png`).
    """

    photo: Photo
    alpha: np.ndarray
    note: str = ""
    estimated: np.ndarray | None = None
    mask_out: Path | None = None

    def write_mask_into(self, stage: Path) -> None:
        """Write the estimated mask (if any) into `stage` under its final name."""
        if self.estimated is not None and self.mask_out is not None:
            _save_png(stage / self.mask_out.name, self.estimated)


@dataclass(frozen=True, kw_only=True)
class RuntimeChoice:
    """Where and in which precision the networks run (`--device`, `--dtype`, `--autocast`).

    Attributes:
        device: `--device`, or None for cuda when torch sees a GPU, else cpu.
        dtype: `--dtype` ("auto" is resolved by the pipeline for the loaded model).
        autocast: `--autocast` / `--no-autocast`, or None: on for `--dtype float16` on CUDA under the
            "neural-gaffer" encoding, as the authors run it (official implementation §2).
        compat: the lighting encoding the model is run with (decides the autocast default).
    """

    device: str | None
    dtype: str
    autocast: bool | None
    compat: str

    def device_name(self, *, check: bool = True) -> str:
        """The torch device; with `check`, a CUDA or MPS device this torch cannot use is refused
        (called before the weights load)."""
        return _device_name(self.device, check=check)

    def runtime_config(self) -> RuntimeConfig:
        """The pipeline's `RuntimeConfig` (imports torch)."""
        from gaffer_diffusion.pipelines import RuntimeConfig

        device = self.device_name(check=False)  # checked before the weights load (`device_name`)
        autocast = self.autocast
        if autocast is None:
            autocast = (
                self.dtype == "float16"
                and device.startswith("cuda")
                and self.compat == "neural-gaffer"
            )
        return RuntimeConfig(device=device, dtype=self.dtype, autocast=bool(autocast))  # type: ignore[arg-type]


@dataclass(frozen=True, kw_only=True)
class ModelChoice:
    """The model and how it is sampled.

    Attributes:
        checkpoint: `--checkpoint` (None: the shipped gaffer-tiny).
        base_model: `--base-model` (the authors' release only).
        sampling: the model's own sampling, read once from its folder, with every sampling flag the
            user gave as an override (`--steps`, `--guidance`, `--average-samples`,
            `--mirror-average`, `--compat`).
        latent_mode: `--latent-mode`, else the one the encoding brings (`latent_mode_for`).
        scheduler: `--scheduler`.
        runtime: device and precision.
        seed: `--seed` (item i uses seed + i where a command samples several).
        batch_size: `--batch-size`.
        full_frame: `--full-frame` (keep the model's whole output, not the input's background).
    """

    checkpoint: Path | None
    base_model: Path | None
    sampling: DefaultSampling
    latent_mode: LatentModeName
    scheduler: str
    runtime: RuntimeChoice
    seed: int
    batch_size: int
    full_frame: bool

    @property
    def compat(self) -> Any:
        """The lighting encoding: `--compat`, else the one the model was trained with."""
        return self.sampling.compat

    def sampling_config(self) -> SamplingConfig:
        """The pipeline's `SamplingConfig`."""
        return self.sampling.sampling_config(latent_mode=self.latent_mode, scheduler=self.scheduler)


@dataclass(frozen=True, kw_only=True)
class EnvmapLight:
    """An environment map read once (`--envmap`, or one map of `--envmaps`) and the camera it is seen
    from (`--w2c`, or `--azimuth/--elevation`).

    Attributes:
        path: the map's file (a bundled HDRI's name is resolved to its file by the parser).
        env: the map, read with `--sanitize`.
        pose: the camera.
    """

    path: Path
    env: EnvironmentMap
    pose: W2CBlender

    @property
    def label(self) -> str:
        """The name of the outputs lit by this map (`OUT/<image>/<label>.png`)."""
        return self.path.stem

    def maps(self, size: int, compat: Any, frames: int = 0) -> LightingMaps:
        """The camera-frame LDR/HDR maps the model is conditioned on; `frames > 1`: one per turntable
        frame, the map spun by 360/frames degrees each (frame k is the authors' frame k)."""
        import torch

        from gaffer_diffusion.conditioning import lighting_from_envmap

        n = max(frames, 1)
        spin = torch.arange(n, dtype=torch.float64) * (360.0 / n) if frames > 1 else 0.0
        return lighting_from_envmap(
            self.env, [self.pose] * n, size=size, compat=compat, spin_deg=spin
        )


@dataclass(frozen=True, kw_only=True)
class EncodedLight:
    """Pre-encoded camera-frame maps (`--ldr`, `--hdr`), read when the model's size is known."""

    ldr: Path
    hdr: Path

    @property
    def label(self) -> str:
        """The name of the outputs lit by these maps."""
        return self.ldr.stem

    def maps(self, size: int, compat: Any = None, frames: int = 0) -> LightingMaps:
        """The two maps, resized to the model's `size` (`compat` and `frames` do not apply: the
        request builder refuses a turntable of pre-encoded maps)."""
        from gaffer_diffusion.conditioning import LightingMaps
        from gaffer_diffusion.evaluation import read_lighting_map

        return LightingMaps(
            ldr=read_lighting_map(self.ldr, size), hdr=read_lighting_map(self.hdr, size)
        )


Light = EnvmapLight | EncodedLight
"""The lighting of one relight output."""


@dataclass(frozen=True, kw_only=True)
class OutputLook:
    """How a model result becomes the image written (`--output-size`, `--detail`, `--background`,
    `--fov`)."""

    output_size: OutputSize
    detail: DetailMode
    background: Background
    fov: float


@dataclass(frozen=True, kw_only=True)
class RelightRequest:
    """`gaffer-diffusion relight`.

    Attributes:
        model: the model and its sampling.
        look: how results are written.
        out: the output PNG, or the output folder (`grid`).
        photos: each photo read, with its object mask: one for one image; a folder's readable ones.
        unreadable: a folder's photos that could not be used ("name: why"), reported at the end.
        lights: the lighting: one (`--envmap`, `--ldr/--hdr`), or each map of `--envmaps`.
        grid: every photo x every light into the folder `out` (a folder of images or `--envmaps`).
        turntable: `--turntable` frames of one map spinning (0 or 1: one image).
        video: `--video` (the turntable's animation format).
        fps: `--fps`.
    """

    model: ModelChoice
    look: OutputLook
    out: Path
    photos: tuple[tuple[Path, PhotoMask], ...]
    unreadable: tuple[str, ...] = ()
    lights: tuple[Light, ...]
    grid: bool
    turntable: int
    video: str
    fps: float


@dataclass(frozen=True, kw_only=True)
class Reports:
    """Where `evaluate` writes its reports, and its perceptual metric.

    Attributes:
        json: `--json`.
        markdown: `--markdown`.
        perceptual: None (`--no-perceptual`), "auto", or the `--lpips-backbone` weights file.
    """

    json: Path | None
    markdown: Path | None
    perceptual: Path | str | None

    def load_perceptual(self) -> Any:
        """The metric `evaluate_images`/`evaluate_dataset` take: None, "auto" or the loaded one."""
        if not isinstance(self.perceptual, Path):
            return self.perceptual
        from gaffer_diffusion.errors import InputValueError, MetricUnavailableError
        from gaffer_diffusion.metrics import load_perceptual

        try:
            return load_perceptual(self.perceptual)
        except MetricUnavailableError as exc:
            raise InputValueError(str(exc)) from exc


@dataclass(frozen=True, kw_only=True)
class EvaluateDatasetRequest:
    """`gaffer-diffusion evaluate --dataset`: relight a gaffer-data render folder and score it.

    Attributes:
        dataset: `--dataset`.
        pairs: the (input, target) pairs, their maps already checked with `--sanitize`.
        input_lighting: `--input-lighting`.
        model: the model and its sampling.
        object_fraction: `--object-fraction`, else the model's framing.
        save_predictions: `--save-predictions`.
        reports: the report files and the perceptual metric.
    """

    dataset: Path
    pairs: tuple[EvalPair, ...]
    input_lighting: int | str
    model: ModelChoice
    object_fraction: float | None
    save_predictions: Path | None
    reports: Reports


@dataclass(frozen=True, kw_only=True)
class EvaluateFoldersRequest:
    """`gaffer-diffusion evaluate --pred --gt`: score images against ground truth matched by name.

    Attributes:
        pred: `--pred`.
        gt: `--gt`.
        names: the file names both hold, sorted.
        masks: `[N, 1, H, W]` masks of `--mask-dir` (read and checked), or None.
        reports: the report files and the perceptual metric.
    """

    pred: Path
    gt: Path
    names: tuple[str, ...]
    masks: Any  # torch.Tensor | None
    reports: Reports


EvaluateRequest = EvaluateDatasetRequest | EvaluateFoldersRequest
"""`gaffer-diffusion evaluate`, in either of its two modes."""


@dataclass(frozen=True, kw_only=True)
class InsertRequest:
    """`gaffer-diffusion insert`.

    Attributes:
        object: the object photo (OBJECT) read, with its mask.
        background: the background photo (`--into`) read.
        placement: where the object goes and how tall (`--at`, `--height`).
        lighting: the background's lighting (`--envmap`, `--light-from-photo` with its key light,
            or `--light-source`), with the camera and the sentence the report says of it.
        model: the model and its sampling.
        out: the output PNG.
        save_envmap: `--save-envmap`.
        shadow: `--shadow`.
        detail: `--detail`.
    """

    object: PhotoMask
    background: Photo
    placement: Placement
    lighting: InsertLighting
    model: ModelChoice
    out: Path
    save_envmap: Path | None
    shadow: ShadowMode
    detail: DetailMode
