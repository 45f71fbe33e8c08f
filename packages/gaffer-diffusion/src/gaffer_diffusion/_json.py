"""Strict JSON for reports: never `Infinity` or `NaN`, which `json.dumps` writes by default
and strict parsers (JavaScript's `JSON.parse`, `jq`, Python with `parse_constant`) reject.

A non-finite number is written as `null`, and the document's top-level `"non_finite"` object maps the
JSON Pointer (RFC 6901) of each such value to what it was: `"inf"`, `"-inf"` or `"nan"`. The common
case is PSNR of identical images, which is infinite (MSE 0): e.g. `{"psnr": null, ...,
"non_finite": {"/items/0/raw/psnr": "inf"}}`. No cap is substituted, so no made-up number enters a mean.
"""

import json
import math
from typing import Any

NON_FINITE_KEY = "non_finite"
"""Top-level key listing the values written as null (JSON Pointer -> "inf" / "-inf" / "nan")."""


def _pointer_part(key: object) -> str:
    return str(key).replace("~", "~0").replace("/", "~1")


def json_safe(obj: Any, where: dict[str, str] | None = None, path: str = "") -> Any:
    """A copy of `obj` (dicts, lists, tuples, scalars) with non-finite floats replaced by None; their
    JSON Pointers and values are added to `where`."""
    if isinstance(obj, float) and not math.isfinite(obj):
        if where is not None:
            where[path] = "nan" if math.isnan(obj) else ("inf" if obj > 0 else "-inf")
        return None
    if isinstance(obj, dict):
        return {k: json_safe(v, where, f"{path}/{_pointer_part(k)}") for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v, where, f"{path}/{i}") for i, v in enumerate(obj)]
    return obj


def json_dumps(obj: Any, **kwargs: Any) -> str:
    """`json.dumps` that writes strict JSON: non-finite numbers become null and are listed under
    `NON_FINITE_KEY` (when `obj` is a dict); `allow_nan=False` makes any slip an error, not output."""
    where: dict[str, str] = {}
    safe = json_safe(obj, where)
    if where and isinstance(safe, dict):
        safe = {**safe, NON_FINITE_KEY: where}
    return json.dumps(safe, allow_nan=False, **kwargs)
