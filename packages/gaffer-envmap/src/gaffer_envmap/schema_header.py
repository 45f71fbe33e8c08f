"""The one check of a JSON file's `schema` / `schema_version` header, shared by every package.

gaffer-data's manifests, gaffer-diffusion's model folders and training checkpoints all carry
`{"schema": NAME, "schema_version": "MAJOR.MINOR", ...}`. `schema_header_problem` says what is wrong
with such a header, the same way for all of them; each reader raises its own error with its own
advice (one schema-header helper instead of three hand-written checks).
"""

from typing import Literal

SchemaProblem = Literal[
    "no_header", "foreign_schema", "malformed_version", "other_major", "newer_minor"
]
"""What is wrong with a header: not a JSON object or a key missing; another `schema` name; a
`schema_version` that is not "MAJOR.MINOR"; another MAJOR version than the reader's (it cannot read
the file); a newer MINOR version (readable, its unknown fields ignored)."""


def parse_schema_version(text: object) -> tuple[int, int] | None:
    """`(major, minor)` of a "MAJOR.MINOR" string, or None when it is not one.

    Example:
        >>> parse_schema_version("1.2"), parse_schema_version("1"), parse_schema_version(None)
        ((1, 2), None, None)
    """
    try:
        major, minor = str(text).split(".")
        return int(major), int(minor)
    except ValueError:
        return None


def schema_header_problem(data: object, *, schema: str, version: str) -> SchemaProblem | None:
    """What is wrong with `data`'s header for a reader of `schema` at "MAJOR.MINOR" `version`
    (None: the reader understands the file). Checked in this order: header present, schema name,
    version syntax, MAJOR, MINOR.

    Example:
        >>> h = {"schema": "gaffer.object", "schema_version": "1.3"}
        >>> schema_header_problem(h, schema="gaffer.object", version="1.1")
        'newer_minor'
        >>> schema_header_problem(h, schema="gaffer.object", version="2.0")
        'other_major'
        >>> schema_header_problem(h, schema="gaffer.model", version="1.0")
        'foreign_schema'
        >>> schema_header_problem([], schema="gaffer.model", version="1.0")
        'no_header'
    """
    if not isinstance(data, dict) or "schema" not in data or "schema_version" not in data:
        return "no_header"
    if data["schema"] != schema:
        return "foreign_schema"
    got = parse_schema_version(data["schema_version"])
    if got is None:
        return "malformed_version"
    ours = parse_schema_version(version)
    if ours is None:
        raise ValueError(f"the reader's version {version!r} is not 'MAJOR.MINOR'")
    if got[0] != ours[0]:
        return "other_major"
    if got[1] > ours[1]:
        return "newer_minor"
    return None
