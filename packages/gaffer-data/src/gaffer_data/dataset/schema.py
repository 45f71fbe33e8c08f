"""Typed, frozen records of a rendered relighting dataset (the artifact schema), pure Python + numpy.

On disk a dataset is a folder:

```
OUT/
  dataset.json                      # schema "gaffer.render_dataset": config, object ids, failures
  objects/<object_id>/
    manifest.json                   # schema "gaffer.rendered_object"; written last = completion marker
    cameras.npz                     # w2c_blender [V, 3, 4], c2w_opencv [V, 4, 4], intrinsics [3, 3]
    lit/{VVV}_{LLL}.exr|.png        # view VVV under environment-map draw LLL
    area/{VVV}.exr|.png             # view VVV under the random area light, grey world
    alpha/{VVV}.png                 # object mask, 8-bit
    normal/{VVV}.exr                # world-space (Blender, z up) shading normals, float32 RGB
    albedo/{VVV}.exr                # diffuse colour (albedo), linear float32 RGB
    depth/{VVV}.exr                 # distance along the camera axis (Blender "Z" pass), float32
    transforms_{train,test}.json    # multi-view sets only: NeRF-Synthetic cameras (Blender/OpenGL c2w)
```

A multi-view set (`RenderConfig.multiview`, `gaffer-data render-multiview`) has the same layout; its
views carry `split` ("train" first, then "test") and every view shares the same lighting draws.

EXRs are linear Rec.709 float32 with premultiplied alpha (the OpenEXR convention); PNGs are 8-bit sRGB
display images through the config's view transform, with straight (unpremultiplied) alpha.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from gaffer_data.config import RenderConfig
from gaffer_data.dataset.poses import CameraPoses, load_poses

OBJECT_SCHEMA = "gaffer.rendered_object"
"""Schema name of an object's `manifest.json`."""
OBJECT_SCHEMA_VERSION = "1.2"
"""MAJOR.MINOR version this package writes and reads (see `gaffer_data.dataset.manifest`).

1.1 added `ViewRecord.split`, `RenderConfig.multiview` and the `transforms` payloads (multi-view sets).
1.2 added `RenderConfig.envmap_sanitize` (`--sanitize`; a 1.1 manifest reads as the default "raise",
though its maps were rendered as Blender loaded them, unsanitized).
"""
DATASET_SCHEMA = "gaffer.render_dataset"
"""Schema name of a dataset's top-level `dataset.json`."""
DATASET_SCHEMA_VERSION = "1.2"
"""MAJOR.MINOR version of `dataset.json`; version 1.2 added `config.envmap_sanitize`, as in
`OBJECT_SCHEMA_VERSION`."""

Split = Literal["train", "test"]
"""The split of a view in a multi-view set."""
ColorSpace = Literal["linear_rec709", "srgb", "data"]
"""`linear_rec709`: scene-linear EXR; `srgb`: 8-bit display PNG; `data`: non-colour (normals, depth)."""
FileKind = Literal[
    "lit_exr",
    "lit_png",
    "area_exr",
    "area_png",
    "alpha",
    "normal",
    "albedo",
    "depth",
    "cameras",
    "envmap_ldr",
    "envmap_hdr",
    "transforms",
]
"""What a payload holds; `envmap_ldr`/`envmap_hdr` are the authors' camera-frame lighting maps
(converted datasets), `transforms` a NeRF-Synthetic `transforms_*.json` (multi-view sets)."""


@dataclass(frozen=True, kw_only=True)
class Producer:
    """Which package and version wrote an artifact."""

    package: str
    version: str


@dataclass(frozen=True, kw_only=True)
class FileRecord:
    """One payload file of an object, relative to the object folder.

    Attributes:
        path: POSIX path relative to the object folder.
        sha256: hex digest of the file's bytes.
        kind: what the file holds (see `FileKind`).
        dtype: element type of the decoded pixels ("float32", "uint8") or "npz".
        shape: decoded array shape, e.g. `(H, W, 4)`; empty for NPZ.
        color_space: colour encoding (see `ColorSpace`).
    """

    path: str
    sha256: str
    kind: FileKind
    dtype: str
    shape: tuple[int, ...]
    color_space: ColorSpace


@dataclass(frozen=True, kw_only=True)
class EnvmapRef:
    """Which environment map (and augmentation) lit an image.

    The world texture was `AugmentSpec(flip, yaw_step, num_steps).apply(read_envmap(source,
    sanitize=config.envmap_sanitize))` from gaffer-envmap (schema 1.2; before, the unsanitized
    pixels), in Blender's convention (z up, u = 0.5 - atan2(y, x) / 2pi), at world `strength`: first
    the horizontal mirror (if `flip`), then a roll by `yaw_step / num_steps` of a turn.

    Attributes:
        name: the pool entry's name (file stem).
        source: the file path as it was given to the renderer.
        source_sha256: hex digest of the source file, to find it again after a move.
        flip: mirrored horizontally.
        yaw_step: roll in steps of `1 / num_steps` turn.
        num_steps: steps per turn (1 = no yaw augmentation).
        strength: Blender world strength (paper: 1).
    """

    name: str
    source: str
    source_sha256: str
    flip: bool
    yaw_step: int
    num_steps: int
    strength: float = 1.0


@dataclass(frozen=True, kw_only=True)
class AreaLightSample:
    """The random area light of one view (paper §3.1), in Blender world coordinates (z up).

    Attributes:
        location: light position; the light faces down (-z).
        energy: power in watts.
        scale: object scale of the 1 m square light.
        world_grey: linear grey level of the uniform world.
    """

    location: tuple[float, float, float]
    energy: float
    scale: float
    world_grey: float


@dataclass(frozen=True, kw_only=True)
class CameraSample:
    """The sampled camera of one view; it looks at the origin with +z up.

    Attributes:
        elevation_deg: elevation above the xy plane.
        azimuth_deg: azimuth from +x towards +y.
        distance: distance to the origin.
        position: `(x, y, z)` = distance * (cos e cos a, cos e sin a, sin e).
    """

    elevation_deg: float
    azimuth_deg: float
    distance: float
    position: tuple[float, float, float]


@dataclass(frozen=True, kw_only=True)
class LitImage:
    """One render of a view under one environment-map draw (paths relative to the object folder)."""

    lighting_index: int
    envmap: EnvmapRef
    exr: str
    png: str


@dataclass(frozen=True, kw_only=True)
class AreaLightImage:
    """The area-light render of a view and its passes (paths relative to the object folder)."""

    light: AreaLightSample
    exr: str
    png: str
    normal: str
    albedo: str
    depth: str


@dataclass(frozen=True, kw_only=True)
class ViewRecord:
    """One camera view of an object and every image rendered from it.

    Attributes:
        index: view index `VVV`.
        camera: the sampled camera.
        lit: the environment-map renders, in lighting order.
        area: the area-light render, or None when the config disabled it.
        alpha: path of the 8-bit object mask, or None when no render had a transparent film.
        split: "train" or "test" in a multi-view set; None in the relighting dataset.
    """

    index: int
    camera: CameraSample
    lit: tuple[LitImage, ...]
    area: AreaLightImage | None
    alpha: str | None
    split: Split | None = None


@dataclass(frozen=True, kw_only=True)
class Intrinsics:
    """Pinhole intrinsics in pixels (OpenCV convention: x right, y down, pixel centres at +0.5)."""

    width: int
    height: int
    fx: float | int
    fy: float | int
    cx: float | int
    cy: float | int

    def matrix(self) -> np.ndarray:
        """The `[3, 3]` float64 OpenCV camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, kw_only=True)
class Normalization:
    """How the source scene was moved into the unit box: `p_render = scale * (p_source - center)`."""

    scale: float
    center: tuple[float, float, float]


@dataclass(frozen=True, kw_only=True)
class ObjectPlan:
    """Everything decided before rendering an object: sampled cameras, draws and output paths.

    The planner (`gaffer_data.render.plan`) builds it from (config, seed, object id); the worker renders
    it; the manifest is this plan plus the file records.
    """

    object_id: str
    source: str
    views: tuple[ViewRecord, ...]
    intrinsics: Intrinsics
    config: RenderConfig


@dataclass(frozen=True, kw_only=True)
class RenderedObject:
    """A completely rendered object, as read from its `manifest.json`.

    Attributes:
        object_id: the object's id (its folder name).
        root: the object folder; every relative path resolves against it.
        source: path of the source mesh as given to the renderer.
        source_sha256: digest of the source file.
        normalization: how the source scene was moved into the unit box.
        views: one record per view.
        intrinsics: the shared pinhole intrinsics.
        config: the config the object was rendered with.
        files: every payload with its digest.
        producer: the package that wrote the manifest.
        schema_version: the manifest's "MAJOR.MINOR".
        created_utc: ISO-8601 time the manifest was written.
    """

    object_id: str
    root: Path
    source: str
    source_sha256: str
    normalization: Normalization
    views: tuple[ViewRecord, ...]
    intrinsics: Intrinsics
    config: RenderConfig
    files: tuple[FileRecord, ...]
    producer: Producer
    schema_version: str
    created_utc: str

    def path(self, relative: str) -> Path:
        """Absolute path of a payload given its manifest-relative path."""
        return self.root / relative

    def split_views(self, split: Split) -> tuple[ViewRecord, ...]:
        """The views of one split of a multi-view set ("train" or "test"); empty otherwise."""
        return tuple(v for v in self.views if v.split == split)

    def transforms_path(self, split: Split) -> Path:
        """`transforms_{split}.json` of a multi-view set (NeRF-Synthetic format, see `nerf_transforms`)."""
        return self.root / f"transforms_{split}.json"

    def poses(self) -> CameraPoses:
        """Load `cameras.npz` (with `allow_pickle=False`).

        Raises:
            IntegrityError: when the file is missing or lacks a key or has the wrong shapes.
        """
        return load_poses(self.root / "cameras.npz", len(self.views))


@dataclass(frozen=True, kw_only=True)
class RelightSample:
    """One (object, view, lighting) training sample, with everything a diffusion dataloader needs.

    Attributes:
        object_id: the object.
        view_index: the view `VVV`.
        lighting_index: the envmap draw `LLL`.
        image_exr: linear RGBA float32 EXR (premultiplied alpha).
        image_png: sRGB RGBA PNG (straight alpha).
        alpha: the object mask PNG, or None.
        envmap: the lighting (source map + augmentation) in Blender's world convention.
        w2c_blender: `[3, 4]` world-to-camera in Blender camera axes.
        c2w_opencv: `[4, 4]` camera-to-world in OpenCV camera axes.
    """

    object_id: str
    view_index: int
    lighting_index: int
    image_exr: Path
    image_png: Path
    alpha: Path | None
    envmap: EnvmapRef
    w2c_blender: np.ndarray
    c2w_opencv: np.ndarray


@dataclass(frozen=True, kw_only=True)
class FailureRecord:
    """An object that could not be rendered after its retries."""

    object_id: str
    source: str
    attempts: int
    reason: str
