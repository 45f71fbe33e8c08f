"""Read rendered datasets without Blender: manifests, poses and training samples.

Example:
    >>> from gaffer_data.dataset import open_dataset  # doctest: +SKIP
    >>> ds = open_dataset("renders/")  # doctest: +SKIP
    >>> for sample in ds.iter_samples():  # doctest: +SKIP
    ...     print(sample.image_exr, sample.envmap.name, sample.c2w_opencv.shape)
"""

import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gaffer_data.config import RenderConfig
from gaffer_data.dataset.manifest import (
    check_schema,
    object_from_json,
    read_json,
    sha256_file,
)
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    CameraPoses,
    FailureRecord,
    RelightSample,
    RenderedObject,
)
from gaffer_data.errors import InputError, IntegrityError

MANIFEST_NAME = "manifest.json"
"""An object folder is complete iff this file exists (it is written atomically, last)."""
DATASET_NAME = "dataset.json"
OBJECTS_DIR = "objects"


def load_poses(path: Path, num_views: int | None = None) -> CameraPoses:
    """Load a `cameras.npz` payload.

    Args:
        path: the NPZ file.
        num_views: expected V, or None to accept any.

    Raises:
        IntegrityError: missing file, missing key or wrong shapes.
    """
    try:
        with np.load(path, allow_pickle=False) as npz:
            w2c = np.array(npz["w2c_blender"], dtype=np.float64)
            c2w = np.array(npz["c2w_opencv"], dtype=np.float64)
            k = np.array(npz["intrinsics"], dtype=np.float64)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
        raise IntegrityError(
            f"`{path}` is not a valid cameras NPZ ({exc!r}); re-render the object."
        ) from exc
    v = w2c.shape[0] if num_views is None else num_views
    if w2c.shape != (v, 3, 4) or c2w.shape != (v, 4, 4) or k.shape != (3, 3):
        raise IntegrityError(
            f"`{path}` holds w2c_blender {w2c.shape}, c2w_opencv {c2w.shape}, intrinsics {k.shape}; "
            f"expected ({v}, 3, 4), ({v}, 4, 4), (3, 3)."
        )
    for arr in (w2c, c2w, k):
        arr.flags.writeable = False
    return CameraPoses(w2c_blender=w2c, c2w_opencv=c2w, intrinsics=k)


def read_object(folder: str | Path, *, verify: bool = False) -> RenderedObject:
    """Read one rendered object folder.

    Args:
        folder: the object folder (holding `manifest.json`).
        verify: also check that every payload exists and matches its sha256 (reads every byte).

    Returns:
        The object's typed record.

    Raises:
        ManifestError: the manifest is missing or malformed (the object is incomplete).
        SchemaVersionError: the manifest's MAJOR version differs from this reader's.
        IntegrityError: with `verify`, a payload is missing or corrupt.
    """
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    obj = object_from_json(read_json(manifest), folder, where=f"`{manifest}`")
    if verify:
        verify_object(obj)
    return obj


def verify_object(obj: RenderedObject) -> None:
    """Check every payload of `obj` against its recorded sha256.

    Raises:
        IntegrityError: naming the first missing or corrupt file.
    """
    for record in obj.files:
        path = obj.path(record.path)
        if not path.is_file():
            raise IntegrityError(
                f"`{path}` is listed in the manifest but missing; re-render the object."
            )
        digest = sha256_file(path)
        if digest != record.sha256:
            raise IntegrityError(
                f"`{path}` has sha256 {digest[:12]}…, the manifest says {record.sha256[:12]}…; "
                "the file was modified or truncated: re-render the object."
            )


def iter_object_samples(obj: RenderedObject) -> Iterator[RelightSample]:
    """Every (view, lighting) sample of one object, in view then lighting order."""
    poses = obj.poses()
    for view in obj.views:
        for lit in view.lit:
            yield RelightSample(
                object_id=obj.object_id,
                view_index=view.index,
                lighting_index=lit.lighting_index,
                image_exr=obj.path(lit.exr),
                image_png=obj.path(lit.png),
                alpha=None if view.alpha is None else obj.path(view.alpha),
                envmap=lit.envmap,
                w2c_blender=poses.w2c_blender[view.index],
                c2w_opencv=poses.c2w_opencv[view.index],
            )


@dataclass(frozen=True, kw_only=True)
class RenderDataset:
    """A rendered dataset folder: its complete objects, its failures and its config.

    Attributes:
        root: the dataset folder.
        object_ids: ids of complete objects (those with a manifest), sorted.
        failures: objects the renderer gave up on.
        config: the render config from `dataset.json`, or None when the file is absent.
    """

    root: Path
    object_ids: tuple[str, ...]
    failures: tuple[FailureRecord, ...]
    config: RenderConfig | None

    def __len__(self) -> int:
        return len(self.object_ids)

    def object(self, object_id: str, *, verify: bool = False) -> RenderedObject:
        """Read one object by id.

        Raises:
            InputError: the id is not a complete object of this dataset.
        """
        if object_id not in self.object_ids:
            raise InputError(
                f"`object_id`={object_id!r} is not a complete object of `{self.root}` "
                f"({len(self.object_ids)} objects; see `.object_ids`)."
            )
        return read_object(self.root / OBJECTS_DIR / object_id, verify=verify)

    def iter_objects(self, *, verify: bool = False) -> Iterator[RenderedObject]:
        """Every complete object, in id order."""
        for object_id in self.object_ids:
            yield self.object(object_id, verify=verify)

    def iter_samples(self) -> Iterator[RelightSample]:
        """Every (object, view, lighting) sample of the dataset."""
        for obj in self.iter_objects():
            yield from iter_object_samples(obj)


def open_dataset(root: str | Path) -> RenderDataset:
    """Open a rendered dataset folder (complete or partially rendered).

    Args:
        root: the folder given as `--out` to `gaffer-data render`.

    Returns:
        The dataset index. Objects without a manifest (still rendering or killed) are not listed.

    Raises:
        InputError: `root` is not a folder.
        SchemaVersionError: `dataset.json` has a different MAJOR version.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(
            f"`root`={str(root)!r} is not a folder; pass the `--out` folder of a render."
        )
    ids = tuple(
        sorted(
            p.parent.name for p in (root / OBJECTS_DIR).glob(f"*/{MANIFEST_NAME}") if p.is_file()
        )
    )
    config = None
    failures: tuple[FailureRecord, ...] = ()
    if (root / DATASET_NAME).is_file():
        data = read_json(root / DATASET_NAME)
        where = f"`{root / DATASET_NAME}`"
        check_schema(data, schema=DATASET_SCHEMA, version=DATASET_SCHEMA_VERSION, where=where)
        config = RenderConfig.from_dict(data["config"]) if "config" in data else None
        failures = tuple(
            FailureRecord(
                object_id=str(f["object_id"]),
                source=str(f["source"]),
                attempts=int(f["attempts"]),
                reason=str(f["reason"]),
            )
            for f in data.get("failures", [])
            if f.get("object_id") not in ids
        )
    return RenderDataset(root=root, object_ids=ids, failures=failures, config=config)
