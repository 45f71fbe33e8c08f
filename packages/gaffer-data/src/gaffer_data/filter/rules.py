"""Typed filtering rules (paper §3.1: bounding boxes, BRDF attributes, file size), each with a reason."""

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path

from gaffer_data.errors import ConfigError
from gaffer_data.filter.features import ObjectFeatures


@dataclass(frozen=True, kw_only=True)
class RuleOutcome:
    """The result of one rule on one object."""

    rule: str
    passed: bool
    value: float | str | None
    limit: float | str | None
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
    """

    max_file_mb: float = 200.0
    min_faces: int = 4
    max_faces: int = 2_000_000
    max_aspect_ratio: float = 50.0
    max_components: int = 5_000
    max_non_manifold_fraction: float = 0.5
    max_degenerate_fraction: float = 0.2
    max_transmission: float = 0.5
    min_alpha: float = 0.5
    max_emission: float = 1.0
    require_material: bool = False

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
        return cls(**data)

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

        def check(rule: str, value: float, limit: float, ok: bool, what: str) -> None:
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
