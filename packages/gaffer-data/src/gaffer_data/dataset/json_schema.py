"""JSON Schema (draft 2020-12) of the versioned manifests, generated from the frozen dataclasses.

`object_manifest_schema()` describes an object's `manifest.json` (`gaffer.rendered_object`),
`dataset_manifest_schema()` a dataset's `dataset.json` (`gaffer.render_dataset`), and
`authors_object_manifest_schema()` / `authors_dataset_manifest_schema()` the same two files written by
`gaffer-data convert-authors` (`gaffer.authors_object`, `gaffer.authors_dataset`); `write_schemas`
writes all four (`gaffer-data schema --out DIR`) so other languages and tools can validate manifests.

Generated from the same dataclasses the writer serialises with `dataclasses.asdict` (for the converted
layout, the dataclasses its reader builds from each entry), so the schemas cannot drift from the code. They encode the reader's version rule: any `1.x` version validates, a
dataclass field is required only when it has no default (fields with defaults were added in later
MINOR versions or are filled in by the reader), top-level fields when every 1.x writer wrote them and
the code reads them, and unknown fields are allowed (newer MINOR versions add some).
"""

import dataclasses
import json
import types
import typing
from pathlib import Path
from typing import Any

from gaffer_data._atomic import atomic_write_json
from gaffer_data.config import RenderConfig
from gaffer_data.dataset.authors import (
    AUTHORS_DATASET_SCHEMA,
    AUTHORS_DATASET_SCHEMA_VERSION,
    AUTHORS_OBJECT_SCHEMA,
    AUTHORS_OBJECT_SCHEMA_VERSION,
    AuthorsView,
    HdrFolder,
)
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    OBJECT_SCHEMA,
    OBJECT_SCHEMA_VERSION,
    FailureRecord,
    FileRecord,
    Intrinsics,
    Normalization,
    Producer,
    ViewRecord,
)

DRAFT = "https://json-schema.org/draft/2020-12/schema"
_HEX64 = {"type": "string", "pattern": "^[0-9a-f]{64}$"}
_FIELD_OVERRIDES: dict[str, dict[str, Any]] = {"sha256": _HEX64, "source_sha256": _HEX64}


class _Builder:
    """Turns type hints into schemas, collecting one `$defs` entry per dataclass."""

    def __init__(self) -> None:
        self.defs: dict[str, dict[str, Any]] = {}

    def of(self, tp: Any) -> dict[str, Any]:
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if tp is type(None):
            return {"type": "null"}
        if tp is bool:  # before int: bool subclasses int
            return {"type": "boolean"}
        if tp is int:
            return {"type": "integer"}
        if tp is float:
            return {"type": "number"}
        if tp in (str, Path):
            return {"type": "string"}
        if tp is Any:
            return {}
        if origin is typing.Literal:
            return {"enum": list(args)}
        if origin in (typing.Union, types.UnionType):
            return {"anyOf": [self.of(a) for a in args]}
        if origin is tuple:
            if len(args) == 2 and args[1] is Ellipsis:
                return {"type": "array", "items": self.of(args[0])}
            n = len(args)
            items = [self.of(a) for a in args]
            return {"type": "array", "prefixItems": items, "minItems": n, "maxItems": n}
        if origin is list:
            return {"type": "array", "items": self.of(args[0])}
        if dataclasses.is_dataclass(tp) and isinstance(tp, type):
            return self.dataclass_ref(tp)
        raise TypeError(f"no JSON Schema for the type {tp!r}; extend `_Builder.of`.")

    def dataclass_ref(self, cls: type) -> dict[str, Any]:
        name = cls.__name__
        if name not in self.defs:
            self.defs[name] = {}  # placeholder: stops recursion
            hints = typing.get_type_hints(cls)
            props, required = {}, []
            for f in dataclasses.fields(cls):
                props[f.name] = _FIELD_OVERRIDES.get(f.name) or self.of(hints[f.name])
                no_default = f.default is dataclasses.MISSING
                if no_default and f.default_factory is dataclasses.MISSING:
                    required.append(f.name)
            doc = (cls.__doc__ or "").strip().split("\n")[0]
            self.defs[name] = {
                "type": "object",
                "description": doc,
                "properties": props,
                "required": required,
            }
        return {"$ref": f"#/$defs/{name}"}


def _header(schema: str, version: str, title: str) -> tuple[dict[str, Any], dict[str, Any]]:
    major = version.split(".")[0]
    meta = {
        "$schema": DRAFT,
        "$id": schema_filename(schema, version),
        "title": title,
        "x-gaffer-schema": schema,
        "x-gaffer-schema-version": version,
    }
    props = {
        "schema": {"const": schema},
        "schema_version": {"type": "string", "pattern": f"^{major}\\.[0-9]+$"},
        "created_utc": {"type": "string", "format": "date-time"},
    }
    return meta, props


def _document(
    meta: dict[str, Any], props: dict[str, Any], required: list[str], builder: _Builder
) -> dict[str, Any]:
    return {
        **meta,
        "type": "object",
        "properties": props,
        "required": ["schema", "schema_version", *required],
        "$defs": dict(sorted(builder.defs.items())),
    }


def object_manifest_schema() -> dict[str, Any]:
    """JSON Schema of an object's `manifest.json` (`gaffer.rendered_object`, this package's version)."""
    b = _Builder()
    meta, props = _header(
        OBJECT_SCHEMA, OBJECT_SCHEMA_VERSION, "gaffer-data rendered object manifest"
    )
    props.update(
        producer=b.of(Producer),
        object_id={"type": "string"},
        source={"type": "string"},
        source_sha256=_HEX64,
        intrinsics=b.of(Intrinsics),
        views={"type": "array", "items": b.of(ViewRecord)},
        config=b.of(RenderConfig),
        normalization=b.of(Normalization),
        files={"type": "array", "items": b.of(FileRecord)},
    )
    required = [k for k in props if k not in ("schema", "schema_version", "created_utc")]
    return _document(meta, props, required, b)


def dataset_manifest_schema() -> dict[str, Any]:
    """JSON Schema of a dataset's `dataset.json` (`gaffer.render_dataset`, this package's version)."""
    b = _Builder()
    meta, props = _header(
        DATASET_SCHEMA, DATASET_SCHEMA_VERSION, "gaffer-data rendered dataset manifest"
    )
    props.update(
        producer=b.of(Producer),
        config=b.of(RenderConfig),
        objects={"type": "array", "items": {"type": "string"}},
        failures={"type": "array", "items": b.of(FailureRecord)},
    )
    return _document(meta, props, ["config", "objects"], b)


def authors_object_manifest_schema() -> dict[str, Any]:
    """JSON Schema of a converted object's `manifest.json` (`gaffer.authors_object`).

    Views are described by `AuthorsView` / `AuthorsLitImage`, the records `read_authors_object`
    builds from each entry; every top-level field but `created_utc` is required, as the reader needs
    it.
    """
    b = _Builder()
    meta, props = _header(
        AUTHORS_OBJECT_SCHEMA,
        AUTHORS_OBJECT_SCHEMA_VERSION,
        "gaffer-data converted object manifest",
    )
    props.update(
        producer=b.of(Producer),
        object_id={"type": "string"},
        source={"type": "string"},
        hdr_folder=b.of(HdrFolder),
        intrinsics=b.of(Intrinsics),
        views={"type": "array", "items": b.of(AuthorsView)},
        files={"type": "array", "items": b.of(FileRecord)},
    )
    required = [k for k in props if k not in ("schema", "schema_version", "created_utc")]
    return _document(meta, props, required, b)


def authors_dataset_manifest_schema() -> dict[str, Any]:
    """JSON Schema of a converted dataset's `dataset.json` (`gaffer.authors_dataset`)."""
    b = _Builder()
    meta, props = _header(
        AUTHORS_DATASET_SCHEMA,
        AUTHORS_DATASET_SCHEMA_VERSION,
        "gaffer-data converted dataset manifest",
    )
    props.update(
        producer=b.of(Producer),
        source={"type": "string"},
        lighting={"type": ["string", "null"]},
        objects={"type": "array", "items": {"type": "string"}},
        skipped={"type": "array", "items": b.of(FailureRecord)},
        envmap_names={"type": "array", "items": {"type": "string"}},
    )
    return _document(meta, props, ["source"], b)


def schema_filename(schema: str, version: str) -> str:
    """`<schema>-<version>.schema.json`, e.g. `gaffer.rendered_object-1.1.schema.json`."""
    return f"{schema}-{version}.schema.json"


def write_schemas(out: str | Path) -> tuple[Path, ...]:
    """Write the rendered and converted manifest schemas into folder `out` (created); returns the
    files."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    docs = (
        object_manifest_schema(),
        dataset_manifest_schema(),
        authors_object_manifest_schema(),
        authors_dataset_manifest_schema(),
    )
    for doc in docs:
        json.dumps(doc, allow_nan=False)  # fail before writing if something is not JSON
        paths.append(atomic_write_json(out / doc["$id"], doc))
    return tuple(paths)
