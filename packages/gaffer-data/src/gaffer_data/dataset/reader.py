"""Read rendered datasets without Blender: manifests, poses and training samples.

Example:
    >>> from gaffer_data.dataset import open_dataset  # doctest: +SKIP
    >>> ds = open_dataset("renders/")  # doctest: +SKIP
    >>> for sample in ds.iter_samples():  # doctest: +SKIP
    ...     print(sample.image_exr, sample.envmap.name, sample.c2w_opencv.shape)
"""

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from gaffer_data.config import RenderConfig
from gaffer_data.dataset.manifest import (
    check_schema,
    object_from_json,
    read_json,
    sha256_file,
)

# `load_poses` lived here before `dataset.poses` (import cycle removed); re-exported so that old
# imports keep working.
from gaffer_data.dataset.poses import load_poses as load_poses
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    FailureRecord,
    RelightSample,
    RenderedObject,
)
from gaffer_data.errors import InputError, IntegrityError

MANIFEST_NAME = "manifest.json"
"""An object folder is complete iff this file exists (it is written atomically, last)."""
DATASET_NAME = "dataset.json"
OBJECTS_DIR = "objects"


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
