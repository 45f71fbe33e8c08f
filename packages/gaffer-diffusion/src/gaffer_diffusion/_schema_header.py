"""gaffer-diffusion's reading of a `schema` / `schema_version` header (model folders, training
checkpoints): the shared check `gaffer_envmap.schema_header`, raised as the caller's error.

A file of the same MAJOR version is read whatever its MINOR (unknown fields are ignored).
"""

from typing import Any

from gaffer_envmap.schema_header import schema_header_problem


def check_schema_header(
    data: dict[str, Any],
    *,
    schema: str,
    version: str,
    where: str,
    error: type[Exception],
    advice: str = "",
) -> None:
    """Raise `error` unless `data` has `schema` and a `schema_version` of `version`'s MAJOR.

    Args:
        data: the parsed JSON object.
        schema: the expected `schema` name.
        version: the "MAJOR.MINOR" this reader implements.
        where: the file, for the message.
        error: the exception type to raise (called with the message).
        advice: appended to the version message (e.g. " Upgrade gaffer-diffusion.").
    """
    problem = schema_header_problem(data, schema=schema, version=version)
    if problem is None or problem == "newer_minor":
        return
    found = data.get("schema") if isinstance(data, dict) else None
    if problem == "foreign_schema" or found != schema:
        raise error(f"{where} has schema {found!r}, expected {schema!r}.")
    major = version.split(".")[0]
    raise error(
        f"{where} has schema_version {data.get('schema_version')!r}; this gaffer-diffusion reads "
        f"{major}.x.{advice}"
    )
