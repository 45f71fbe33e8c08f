"""JSON (de)serialisation of manifests, with schema-name and version checks.

Version rule (house style §4.5, after opentelemetry): a manifest with a different MAJOR version raises
`SchemaVersionError`; a newer MINOR version warns with `GafferSchemaWarning` and unknown fields are
ignored; an older MINOR version is read with defaults filled in.
"""

import dataclasses
import datetime
import hashlib
import json
import warnings
from pathlib import Path
from typing import Any

from gaffer_data._version import __version__
from gaffer_data.config import RenderConfig
from gaffer_data.dataset.schema import (
    OBJECT_SCHEMA,
    OBJECT_SCHEMA_VERSION,
    AreaLightImage,
    AreaLightSample,
    CameraSample,
    EnvmapRef,
    FileRecord,
    Intrinsics,
    LitImage,
    Normalization,
    ObjectPlan,
    Producer,
    RenderedObject,
    ViewRecord,
)
from gaffer_data.errors import GafferSchemaWarning, ManifestError, SchemaVersionError
from gaffer_envmap.schema_header import parse_schema_version, schema_header_problem


def sha256_file(path: Path, chunk: int = 1 << 20) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            digest.update(block)
    return digest.hexdigest()


def producer() -> Producer:
    """This package as a `Producer`."""
    return Producer(package="gaffer-data", version=__version__)


def check_schema(data: dict[str, Any], *, schema: str, version: str, where: str) -> tuple[int, int]:
    """Validate a manifest header against the schema this reader understands (the shared check,
    `gaffer_envmap.schema_header`, with gaffer-data's errors and advice).

    Args:
        data: the parsed JSON object.
        schema: expected `schema` name.
        version: the "MAJOR.MINOR" this reader implements.
        where: a description of the file, for messages.

    Returns:
        The manifest's `(major, minor)`.

    Raises:
        SchemaVersionError: different schema name or MAJOR version.
        ManifestError: missing or malformed header.
    """
    problem = schema_header_problem(data, schema=schema, version=version)
    if problem == "no_header":
        raise ManifestError(
            f"{where} has no `schema`/`schema_version` header; it is not a gaffer manifest."
        )
    if problem == "foreign_schema":
        raise SchemaVersionError(
            f"{where} has `schema`={data['schema']!r}, expected {schema!r}; pass the right file."
        )
    got = parse_schema_version(data["schema_version"])
    if got is None:  # "malformed_version"
        raise ManifestError(
            f"`schema_version` in {where} is {data['schema_version']!r}; expected 'MAJOR.MINOR' "
            "such as '1.0'."
        )
    if problem == "other_major":
        raise SchemaVersionError(
            f"{where} has `schema_version`={data['schema_version']!r} but this gaffer-data reads "
            f"{version}; install a gaffer-data whose reader matches MAJOR version {got[0]}."
        )
    if problem == "newer_minor":
        warnings.warn(
            f"{where} has `schema_version`={data['schema_version']!r}, newer than {version}; "
            "unknown fields are ignored (upgrade gaffer-data to read them).",
            GafferSchemaWarning,
            stacklevel=3,
        )
    return got


def utc_now() -> str:
    """The current UTC time as ISO-8601 with a Z suffix."""
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def plan_to_json(plan: ObjectPlan) -> dict[str, Any]:
    """Serialise an `ObjectPlan` (the worker's job and the manifest's body)."""
    return {
        "object_id": plan.object_id,
        "source": plan.source,
        "intrinsics": dataclasses.asdict(plan.intrinsics),
        "views": [dataclasses.asdict(v) for v in plan.views],
        "config": plan.config.to_dict(),
    }


def _tuple3(value: Any) -> tuple[float, float, float]:
    x, y, z = (float(v) for v in value)
    return (x, y, z)


def _view_from_json(d: dict[str, Any]) -> ViewRecord:
    cam = d["camera"]
    area = d.get("area")
    return ViewRecord(
        index=int(d["index"]),
        camera=CameraSample(
            elevation_deg=float(cam["elevation_deg"]),
            azimuth_deg=float(cam["azimuth_deg"]),
            distance=float(cam["distance"]),
            position=_tuple3(cam["position"]),
        ),
        lit=tuple(
            LitImage(
                lighting_index=int(li["lighting_index"]),
                envmap=EnvmapRef(
                    **{
                        k: li["envmap"][k]
                        for k in (f.name for f in dataclasses.fields(EnvmapRef))
                        if k in li["envmap"]
                    }
                ),
                exr=str(li["exr"]),
                png=str(li["png"]),
            )
            for li in d["lit"]
        ),
        area=None
        if area is None
        else AreaLightImage(
            light=AreaLightSample(
                location=_tuple3(area["light"]["location"]),
                energy=float(area["light"]["energy"]),
                scale=float(area["light"]["scale"]),
                world_grey=float(area["light"]["world_grey"]),
            ),
            exr=str(area["exr"]),
            png=str(area["png"]),
            normal=str(area["normal"]),
            albedo=str(area["albedo"]),
            depth=str(area["depth"]),
        ),
        alpha=d.get("alpha"),
        split=d.get("split"),
    )


def plan_from_json(data: dict[str, Any]) -> ObjectPlan:
    """Inverse of `plan_to_json`.

    Raises:
        ManifestError: when a required field is missing or malformed.
    """
    try:
        return ObjectPlan(
            object_id=str(data["object_id"]),
            source=str(data["source"]),
            views=tuple(_view_from_json(v) for v in data["views"]),
            intrinsics=Intrinsics(**data["intrinsics"]),
            config=RenderConfig.from_dict(data["config"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ManifestError(f"malformed object plan/manifest: {exc!r}") from exc


def object_manifest_json(
    plan: ObjectPlan,
    *,
    source_sha256: str,
    normalization: Normalization,
    files: list[FileRecord],
) -> dict[str, Any]:
    """The `manifest.json` body of a completely rendered object."""
    body = plan_to_json(plan)
    return {
        "schema": OBJECT_SCHEMA,
        "schema_version": OBJECT_SCHEMA_VERSION,
        "producer": dataclasses.asdict(producer()),
        "created_utc": utc_now(),
        **body,
        "source_sha256": source_sha256,
        "normalization": dataclasses.asdict(normalization),
        "files": [dataclasses.asdict(f) for f in files],
    }


def object_from_json(data: dict[str, Any], root: Path, *, where: str) -> RenderedObject:
    """Build a `RenderedObject` from a parsed `manifest.json`, checking its schema version.

    Raises:
        SchemaVersionError: different schema or MAJOR version.
        ManifestError: missing or malformed fields.
    """
    check_schema(data, schema=OBJECT_SCHEMA, version=OBJECT_SCHEMA_VERSION, where=where)
    plan = plan_from_json(data)
    try:
        norm = data["normalization"]
        files = tuple(
            FileRecord(
                path=str(f["path"]),
                sha256=str(f["sha256"]),
                kind=f["kind"],
                dtype=str(f["dtype"]),
                shape=tuple(int(s) for s in f["shape"]),
                color_space=f["color_space"],
            )
            for f in data["files"]
        )
        return RenderedObject(
            object_id=plan.object_id,
            root=root,
            source=plan.source,
            source_sha256=str(data["source_sha256"]),
            normalization=Normalization(scale=float(norm["scale"]), center=_tuple3(norm["center"])),
            views=plan.views,
            intrinsics=plan.intrinsics,
            config=plan.config,
            files=files,
            producer=Producer(**data["producer"]),
            schema_version=str(data["schema_version"]),
            created_utc=str(data.get("created_utc", "")),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ManifestError(f"{where} is malformed: {exc!r}; re-render the object.") from exc


def read_json_value(path: Path) -> Any:
    """Parse a JSON file of any type.

    Raises:
        ManifestError: when it is missing or not valid JSON.
    """
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ManifestError(f"`{path}` does not exist; check the path.") from exc
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ManifestError(
            f"`{path}` is not readable JSON ({exc}); delete it and write it again."
        ) from exc


def read_json(path: Path) -> dict[str, Any]:
    """Parse a JSON object file.

    Raises:
        ManifestError: when it is missing or not a JSON object.
    """
    if not Path(path).exists():
        raise ManifestError(f"`{path}` does not exist; is this a gaffer-data folder?")
    data = read_json_value(path)
    if not isinstance(data, dict):
        raise ManifestError(f"`{path}` holds a JSON {type(data).__name__}, expected an object.")
    return data
