"""Typed filtering rules (paper §3.1: bounding boxes, BRDF attributes, file size), each with a reason.

Geometry rules read `ObjectFeatures`; annotation rules (licence, tags, categories, declared faces,
animation) read an Objaverse annotation and run first, so an object they reject is never loaded.
"""

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_data.errors import ConfigError
from gaffer_data.filter.features import ObjectFeatures
from gaffer_data.filter.objaverse import ObjaverseAnnotation

if TYPE_CHECKING:
    _Names = tuple[str, ...]
    _Flag = bool
else:  # from JSON any value reaches these fields; `__post_init__` refuses a wrong one (ConfigError)
    _Names = object
    _Flag = object

_NAME_LISTS = ("allowed_licenses", "excluded_tags", "excluded_categories")


@dataclass(frozen=True, kw_only=True)
class RuleOutcome:
    """The result of one rule on one object."""

    rule: str
    passed: bool
    value: float | int | str | None
    limit: float | int | str | None
    reason: str


@dataclass(frozen=True, kw_only=True)
class FilterRules:
    """Thresholds of the rule-based filter; load from JSON with `FilterRules.from_json`.

    Attributes:
        max_file_mb: reject files larger than this.
        min_faces: reject meshes with fewer triangles.
        max_faces: reject meshes with more triangles.
        max_aspect_ratio: reject thin objects (largest / smallest bbox side).
        max_components: reject objects made of more pieces (scenes, point-like clutter).
        max_non_manifold_fraction: reject if non-manifold edges exceed this fraction of faces.
        max_degenerate_fraction: reject if zero-area faces exceed this fraction of faces.
        max_transmission: reject transparent materials above this transmission.
        min_alpha: reject alpha-blended materials below this alpha.
        max_emission: reject strongly emissive materials.
        require_material: reject objects without any material.
        allowed_licenses: annotated licences to keep (case-insensitive), e.g. `["cc0", "by", "by-sa"]`
            drops Objaverse's non-commercial (`by-nc*`) and no-derivatives (`*-nd`) objects; None keeps
            any licence. An annotated object without a licence is rejected when this is set.
        excluded_tags: reject annotated objects carrying any of these tag names (case-insensitive).
        excluded_categories: reject annotated objects in any of these categories (case-insensitive).
        max_annotated_faces: reject objects whose annotation declares more faces, before loading the
            file; None for no limit.
        reject_animated: reject objects whose annotation declares animations.
        require_annotation: reject objects without an annotation entry (by default they are filtered
            on geometry only, so the annotation rules above do not apply to them).
    """

    max_file_mb: float | int = 200.0
    min_faces: int = 4
    max_faces: int = 2_000_000
    max_aspect_ratio: float | int = 50.0
    max_components: int = 5_000
    max_non_manifold_fraction: float | int = 0.5
    max_degenerate_fraction: float | int = 0.2
    max_transmission: float | int = 0.5
    min_alpha: float | int = 0.5
    max_emission: float | int = 1.0
    require_material: bool = False
    allowed_licenses: _Names | None = None
    excluded_tags: _Names = ()
    excluded_categories: _Names = ()
    max_annotated_faces: int | None = None
    reject_animated: _Flag = False
    require_annotation: _Flag = False

    def __post_init__(self) -> None:
        for name in _NAME_LISTS:
            value = getattr(self, name)
            if value is None and name == "allowed_licenses":
                continue
            if isinstance(value, list):  # from JSON; frozen, so set through object
                value = tuple(value)
                object.__setattr__(self, name, value)
            if not isinstance(value, tuple) or not all(isinstance(v, str) for v in value):
                raise ConfigError(
                    f"`{name}`={value!r} must be a list of strings, e.g. "
                    f"{['cc0', 'by'] if name == 'allowed_licenses' else ['weapon']}."
                )
        faces = self.max_annotated_faces
        if faces is not None and (
            isinstance(faces, bool) or not isinstance(faces, int) or faces < 0
        ):
            raise ConfigError(
                f"`max_annotated_faces`={faces!r} must be a non-negative integer, or null for no limit."
            )
        for name in ("reject_animated", "require_annotation"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"`{name}`={getattr(self, name)!r} must be true or false.")

    @classmethod
    def from_json(cls, path: str | Path) -> "FilterRules":
        """Read rules from a JSON object of field names to values.

        Raises:
            ConfigError: unreadable file, unknown field or wrong type.
        """
        try:
            data = json.loads(Path(path).read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"`rules`={str(path)!r} is not a readable JSON file: {exc}") from exc
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names) if isinstance(data, dict) else ["<not an object>"]
        if unknown:
            raise ConfigError(
                f"`rules`={str(path)!r} has unknown fields {unknown}; valid: {sorted(names)}."
            )
        try:
            return cls(**data)
        except ConfigError as exc:
            raise ConfigError(f"`rules`={str(path)!r}: {exc}") from exc

    def uses_annotations(self) -> bool:
        """Whether any annotation rule is set."""
        return (
            self.allowed_licenses is not None
            or bool(self.excluded_tags or self.excluded_categories)
            or self.max_annotated_faces is not None
            or self.reject_animated
            or self.require_annotation
        )

    def evaluate_annotation(self, annotation: ObjaverseAnnotation | None) -> list[RuleOutcome]:
        """Apply the annotation rules that are set (none for an unannotated object, unless
        `require_annotation`); cheap, so they run before the file is loaded."""
        out: list[RuleOutcome] = []

        def add(
            rule: str,
            ok: bool,
            value: float | int | str | None,
            limit: float | int | str | None,
            reason: str,
        ) -> None:
            out.append(
                RuleOutcome(
                    rule=rule, passed=ok, value=value, limit=limit, reason="" if ok else reason
                )
            )

        if annotation is None:
            if self.require_annotation:
                add("require_annotation", False, None, None, "no annotation entry")
            return out
        a = annotation
        if self.allowed_licenses is not None:
            allowed = ", ".join(self.allowed_licenses)
            ok = a.license is not None and a.license.strip().lower() in {
                lic.lower() for lic in self.allowed_licenses
            }
            reason = f"licence {a.license!r} not allowed (allowed: {allowed})"
            add("allowed_licenses", ok, a.license, allowed, reason)
        for rule, names, excluded in (
            ("excluded_tags", a.tags, self.excluded_tags),
            ("excluded_categories", a.categories, self.excluded_categories),
        ):
            if excluded:
                wanted = {e.lower() for e in excluded}
                hits = sorted({n for n in names if n.lower() in wanted})
                what = "tags" if rule == "excluded_tags" else "categories"
                add(
                    rule,
                    not hits,
                    ", ".join(hits) or None,
                    ", ".join(excluded),
                    f"excluded {what}: {', '.join(hits)}",
                )
        if self.max_annotated_faces is not None:
            n, limit = a.face_count, self.max_annotated_faces
            ok = n is None or n <= limit
            reason = f"annotation declares {n} faces > max_annotated_faces={limit} (not loaded)"
            add("max_annotated_faces", ok, n, limit, reason)
        if self.reject_animated:
            n = a.animation_count
            add("reject_animated", not n, n, 0, f"animated object ({n} animations)")
        return out

    def evaluate(self, features: ObjectFeatures) -> list[RuleOutcome]:
        """Apply every rule; a feature error is itself a failed rule."""
        f = features
        out = [
            RuleOutcome(
                rule="readable",
                passed=f.error is None,
                value=f.error,
                limit=None,
                reason=f.error or "",
            )
        ]
        faces = max(f.face_count, 1)

        def check(rule: str, value: float | int, limit: float | int, ok: bool, what: str) -> None:
            reason = "" if ok else f"{what}: {value:.4g} vs limit {limit:.4g}"
            shown = float(value) if math.isfinite(value) else None  # JSON has no NaN/inf
            out.append(RuleOutcome(rule=rule, passed=ok, value=shown, limit=limit, reason=reason))

        check(
            "max_file_mb",
            f.file_size_mb,
            self.max_file_mb,
            not f.file_size_mb > self.max_file_mb,
            "file too large",
        )
        if f.error is not None:
            return out
        check(
            "min_faces",
            f.face_count,
            self.min_faces,
            f.face_count >= self.min_faces,
            "too few faces",
        )
        check(
            "max_faces",
            f.face_count,
            self.max_faces,
            f.face_count <= self.max_faces,
            "too many faces",
        )
        ratio = f.aspect_ratio
        check(
            "max_aspect_ratio",
            ratio,
            self.max_aspect_ratio,
            math.isfinite(ratio) and ratio <= self.max_aspect_ratio,
            "bounding box too thin",
        )
        check(
            "max_components",
            f.connected_components,
            self.max_components,
            f.connected_components <= self.max_components,
            "too many pieces",
        )
        nm = f.non_manifold_edges / faces
        check(
            "max_non_manifold_fraction",
            nm,
            self.max_non_manifold_fraction,
            nm <= self.max_non_manifold_fraction,
            "too many non-manifold edges",
        )
        dg = f.degenerate_faces / faces
        check(
            "max_degenerate_fraction",
            dg,
            self.max_degenerate_fraction,
            dg <= self.max_degenerate_fraction,
            "too many zero-area faces",
        )
        check("min_surface_area", f.surface_area, 0.0, f.surface_area > 0.0, "zero surface area")
        check(
            "max_transmission",
            f.transmission,
            self.max_transmission,
            f.transmission <= self.max_transmission,
            "transparent material",
        )
        check(
            "min_alpha",
            f.alpha,
            self.min_alpha,
            f.alpha >= self.min_alpha,
            "alpha-blended material",
        )
        check(
            "max_emission",
            f.emission,
            self.max_emission,
            f.emission <= self.max_emission,
            "emissive material",
        )
        if self.require_material:
            check("require_material", f.material_count, 1, f.material_count >= 1, "no material")
        return out
