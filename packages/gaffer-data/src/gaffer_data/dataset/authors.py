"""Schema and pure reader of datasets converted from the Neural Gaffer authors' released layout.

The authors release their renders (e.g. the validation objects) as

```
<split>/<obj>/{VVV}_{LLL}_{env}.png        # view VVV under lighting LLL (environment map `env`)
<split>/<obj>/random_lighting_{VVV}.png    # view VVV under the random area light
<split>/<obj>/{VVV}_RT.npy                 # 3x4 Blender world-to-camera of view VVV
<lighting>/LDR/<obj>/{VVV}_{LLL}_{env}.png           # camera-frame lighting, LDR encoding
<lighting>/HDR_rescaled/<obj>/{VVV}_{LLL}_{env}.png  # (or HDR_normalized/) HDR log encoding
```

(`<lighting>` may also be the object folder itself: `<split>/<obj>/LDR/...`). `gaffer-data
convert-authors` (`gaffer_data.convert.convert_authors`) turns it into this artifact:

```
OUT/
  dataset.json                        # schema "gaffer.authors_dataset": source, objects, skipped, envmaps
  objects/<obj>/
    manifest.json                     # schema "gaffer.authors_object"; written last = completion marker
    cameras.npz                       # w2c_blender [V, 3, 4], c2w_opencv [V, 4, 4], intrinsics [3, 3]
    lit/{VVV}_{LLL}.png               # the authors' image, byte for byte
    area/{VVV}.png                    # random_lighting_{VVV}.png
    envmap_ldr/{VVV}_{LLL}.png        # the authors' camera-frame LDR map of that image
    envmap_hdr/{VVV}_{LLL}.png        # the authors' camera-frame HDR map of that image
```

The lighting maps are the authors' encoding (reference section 4): rotated into the camera frame (layout
"neural-gaffer-camera"), LDR = clip(E, 0, 1)^(1/2.2), HDR = log1p(10 E) / max, both truncated to 8 bit
and squashed to 256x256. They are what the released checkpoint expects as conditioning; they are not
world maps and do not round-trip to radiance. Intrinsics are not in the release: the cameras.npz holds
the authors' 35 mm lens on a 32 mm sensor at the image resolution.
"""

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from gaffer_data.dataset.manifest import check_schema, read_json, sha256_file
from gaffer_data.dataset.poses import load_poses
from gaffer_data.dataset.schema import (
    CameraPoses,
    FailureRecord,
    FileRecord,
    Intrinsics,
    Producer,
)
from gaffer_data.errors import InputError, IntegrityError, ManifestError

AUTHORS_OBJECT_SCHEMA = "gaffer.authors_object"
"""Schema name of a converted object's `manifest.json`."""
AUTHORS_OBJECT_SCHEMA_VERSION = "1.0"
AUTHORS_DATASET_SCHEMA = "gaffer.authors_dataset"
"""Schema name of a converted dataset's `dataset.json`."""
AUTHORS_DATASET_SCHEMA_VERSION = "1.0"

HdrFolder = Literal["HDR_rescaled", "HDR_normalized"]
"""The authors' two names for the folder of HDR-encoded lighting maps (same encoding)."""

MANIFEST_NAME = "manifest.json"
DATASET_NAME = "dataset.json"
OBJECTS_DIR = "objects"


@dataclass(frozen=True, kw_only=True)
class AuthorsLitImage:
    """One of the authors' images of a view under an environment map, with its lighting maps.

    Attributes:
        lighting_index: the authors' `LLL`.
        envmap_name: the `env` part of the file name (e.g. "cannon_2k_225": map name + yaw tag).
        source_name: the authors' file name `{VVV}_{LLL}_{env}.png`.
        png: path of the image, relative to the object folder (RGBA or RGB 8-bit sRGB).
        envmap_ldr: path of the camera-frame LDR lighting map.
        envmap_hdr: path of the camera-frame HDR lighting map.
    """

    lighting_index: int
    envmap_name: str
    source_name: str
    png: str
    envmap_ldr: str
    envmap_hdr: str


@dataclass(frozen=True, kw_only=True)
class AuthorsView:
    """One view of a converted object.

    Attributes:
        index: the authors' view index `VVV`.
        row: the row of this view in `cameras.npz` (views are stored in index order).
        lit: the environment-map images, in lighting order.
        area_png: the random-area-light image (`random_lighting_{VVV}.png`), or None when absent.
    """

    index: int
    row: int
    lit: tuple[AuthorsLitImage, ...]
    area_png: str | None


@dataclass(frozen=True, kw_only=True)
class AuthorsSample:
    """One (object, view, lighting) evaluation sample of a converted dataset.

    Attributes:
        object_id: the object.
        view_index: the view `VVV`.
        lighting_index: the lighting `LLL`.
        envmap_name: the authors' environment-map name.
        image_png: the ground-truth image under that lighting.
        envmap_ldr: its camera-frame LDR lighting map (authors' encoding).
        envmap_hdr: its camera-frame HDR lighting map (authors' encoding).
        area_png: the same view under the random area light, or None.
        w2c_blender: `[3, 4]` world-to-camera in Blender camera axes (the authors' `VVV_RT.npy`).
        c2w_opencv: `[4, 4]` camera-to-world in OpenCV camera axes.
    """

    object_id: str
    view_index: int
    lighting_index: int
    envmap_name: str
    image_png: Path
    envmap_ldr: Path
    envmap_hdr: Path
    area_png: Path | None
    w2c_blender: np.ndarray
    c2w_opencv: np.ndarray


@dataclass(frozen=True, kw_only=True)
class AuthorsObject:
    """A converted object, as read from its `manifest.json`.

    Attributes:
        object_id: the authors' object id (folder name).
        root: the converted object folder.
        source: the authors' object folder it was converted from.
        hdr_folder: which HDR folder name the source used.
        views: the views, in index order.
        intrinsics: the assumed pinhole intrinsics (35 mm lens, 32 mm sensor) at the image size.
        files: every payload with its digest.
        producer: the package that wrote the manifest.
        schema_version: the manifest's "MAJOR.MINOR".
        created_utc: ISO-8601 time the manifest was written.
    """

    object_id: str
    root: Path
    source: str
    hdr_folder: HdrFolder
    views: tuple[AuthorsView, ...]
    intrinsics: Intrinsics
    files: tuple[FileRecord, ...]
    producer: Producer
    schema_version: str
    created_utc: str

    def path(self, relative: str) -> Path:
        """Absolute path of a payload given its manifest-relative path."""
        return self.root / relative

    def poses(self) -> CameraPoses:
        """Load `cameras.npz` (rows follow `AuthorsView.row`).

        Raises:
            IntegrityError: the file is missing or malformed.
        """
        return load_poses(self.root / "cameras.npz", len(self.views))

    def samples(self) -> Iterator[AuthorsSample]:
        """Every (view, lighting) sample of the object, in view then lighting order."""
        poses = self.poses()
        for view in self.views:
            for lit in view.lit:
                yield AuthorsSample(
                    object_id=self.object_id,
                    view_index=view.index,
                    lighting_index=lit.lighting_index,
                    envmap_name=lit.envmap_name,
                    image_png=self.path(lit.png),
                    envmap_ldr=self.path(lit.envmap_ldr),
                    envmap_hdr=self.path(lit.envmap_hdr),
                    area_png=None if view.area_png is None else self.path(view.area_png),
                    w2c_blender=poses.w2c_blender[view.row],
                    c2w_opencv=poses.c2w_opencv[view.row],
                )


@dataclass(frozen=True, kw_only=True)
class AuthorsDataset:
    """A converted dataset folder.

    Attributes:
        root: the converted folder.
        source: the authors' split folder it came from.
        object_ids: complete converted objects, sorted.
        skipped: source objects that could not be converted, with the reason.
        envmap_names: every environment-map name referenced by an image, sorted.
    """

    root: Path
    source: str
    object_ids: tuple[str, ...]
    skipped: tuple[FailureRecord, ...]
    envmap_names: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.object_ids)

    def object(self, object_id: str, *, verify: bool = False) -> AuthorsObject:
        """Read one converted object by id.

        Raises:
            InputError: the id is not a complete object of this dataset.
        """
        if object_id not in self.object_ids:
            raise InputError(
                f"`object_id`={object_id!r} is not a converted object of `{self.root}` "
                f"({len(self.object_ids)} objects; see `.object_ids`)."
            )
        return read_authors_object(self.root / OBJECTS_DIR / object_id, verify=verify)

    def iter_objects(self, *, verify: bool = False) -> Iterator[AuthorsObject]:
        """Every converted object, in id order."""
        for object_id in self.object_ids:
            yield self.object(object_id, verify=verify)

    def iter_samples(self) -> Iterator[AuthorsSample]:
        """Every (object, view, lighting) sample."""
        for obj in self.iter_objects():
            yield from obj.samples()


def file_record_from_json(f: dict[str, Any]) -> FileRecord:
    """A `FileRecord` from its manifest dict."""
    return FileRecord(
        path=str(f["path"]),
        sha256=str(f["sha256"]),
        kind=f["kind"],
        dtype=str(f["dtype"]),
        shape=tuple(int(s) for s in f["shape"]),
        color_space=f["color_space"],
    )


def authors_object_from_json(data: dict[str, Any], root: Path, *, where: str) -> AuthorsObject:
    """Build an `AuthorsObject` from a parsed `manifest.json`, checking its schema version.

    Raises:
        SchemaVersionError: different schema or MAJOR version.
        ManifestError: missing or malformed fields.
    """
    check_schema(
        data, schema=AUTHORS_OBJECT_SCHEMA, version=AUTHORS_OBJECT_SCHEMA_VERSION, where=where
    )
    try:
        views = tuple(
            AuthorsView(
                index=int(v["index"]),
                row=int(v["row"]),
                area_png=None if v.get("area_png") is None else str(v["area_png"]),
                lit=tuple(
                    AuthorsLitImage(
                        lighting_index=int(li["lighting_index"]),
                        envmap_name=str(li["envmap_name"]),
                        source_name=str(li["source_name"]),
                        png=str(li["png"]),
                        envmap_ldr=str(li["envmap_ldr"]),
                        envmap_hdr=str(li["envmap_hdr"]),
                    )
                    for li in v["lit"]
                ),
            )
            for v in data["views"]
        )
        hdr_folder = str(data["hdr_folder"])
        if hdr_folder not in ("HDR_rescaled", "HDR_normalized"):
            raise ValueError(f"hdr_folder {hdr_folder!r}")
        return AuthorsObject(
            object_id=str(data["object_id"]),
            root=root,
            source=str(data["source"]),
            hdr_folder=hdr_folder,  # type: ignore[arg-type]
            views=views,
            intrinsics=Intrinsics(**data["intrinsics"]),
            files=tuple(file_record_from_json(f) for f in data["files"]),
            producer=Producer(**data["producer"]),
            schema_version=str(data["schema_version"]),
            created_utc=str(data.get("created_utc", "")),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ManifestError(f"{where} is malformed: {exc!r}; convert the object again.") from exc


def read_authors_object(folder: str | Path, *, verify: bool = False) -> AuthorsObject:
    """Read one converted object folder.

    Args:
        folder: the object folder (holding `manifest.json`).
        verify: also check every payload against its sha256.

    Raises:
        ManifestError: the manifest is missing or malformed.
        SchemaVersionError: a different schema or MAJOR version.
        IntegrityError: with `verify`, a payload is missing or corrupt.
    """
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    obj = authors_object_from_json(read_json(manifest), folder, where=f"`{manifest}`")
    if verify:
        for record in obj.files:
            path = obj.path(record.path)
            if not path.is_file() or sha256_file(path) != record.sha256:
                raise IntegrityError(
                    f"`{path}` is missing or differs from its recorded sha256; convert it again."
                )
    return obj


def open_authors_dataset(root: str | Path) -> AuthorsDataset:
    """Open a folder written by `gaffer-data convert-authors`.

    Args:
        root: the `--out` folder of the conversion.

    Raises:
        InputError: `root` is not a folder.
        ManifestError: `dataset.json` is missing or malformed.
        SchemaVersionError: `dataset.json` is not a converted dataset or has another MAJOR version.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(
            f"`root`={str(root)!r} is not a folder; pass the `--out` folder of `convert-authors`."
        )
    data = read_json(root / DATASET_NAME)
    where = f"`{root / DATASET_NAME}`"
    check_schema(
        data, schema=AUTHORS_DATASET_SCHEMA, version=AUTHORS_DATASET_SCHEMA_VERSION, where=where
    )
    ids = tuple(
        sorted(
            p.parent.name for p in (root / OBJECTS_DIR).glob(f"*/{MANIFEST_NAME}") if p.is_file()
        )
    )
    try:
        skipped = tuple(
            FailureRecord(
                object_id=str(f["object_id"]),
                source=str(f["source"]),
                attempts=int(f.get("attempts", 1)),
                reason=str(f["reason"]),
            )
            for f in data.get("skipped", [])
            if f.get("object_id") not in ids
        )
        return AuthorsDataset(
            root=root,
            source=str(data["source"]),
            object_ids=ids,
            skipped=skipped,
            envmap_names=tuple(str(n) for n in data.get("envmap_names", [])),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ManifestError(f"{where} is malformed: {exc!r}; convert again.") from exc
