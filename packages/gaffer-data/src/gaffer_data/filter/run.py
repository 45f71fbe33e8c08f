"""`gaffer-data filter`: annotation rules -> features -> rules -> classifier -> one JSONL line per object.

Feature extraction runs in spawned worker processes (`gaffer_data.filter.isolate`), each object under
a time limit and a memory cap, so a loader that hangs, crashes the interpreter (a segfault in a native
mesh library) or swallows memory costs one object, recorded as rejected with its reason, never the run.

`src` may be an Objaverse-style cache (`gaffer_data.filter.objaverse`): the uid is the object id, each
line carries the object's `annotation` (null without one), and the annotation rules run first, so an
object they reject is never loaded (its `features` are null).
"""

import dataclasses
import json
import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_data._atomic import atomic_write_text
from gaffer_data.errors import ConfigError, missing_extra
from gaffer_data.filter.classifier import QualityClassifier
from gaffer_data.filter.features import extract_features
from gaffer_data.filter.isolate import extract_isolated
from gaffer_data.filter.memory_cap import DEFAULT_MAX_WORKER_MEMORY_MB, memory_cap_supported
from gaffer_data.filter.objaverse import (
    ObjaverseAnnotation,
    find_annotation_files,
    find_objaverse_glbs,
    read_annotations,
    scan_objaverse,
)
from gaffer_data.filter.rules import FilterRules
from gaffer_data.recipes import scan_objects

if TYPE_CHECKING:
    _CountArg = int
else:  # at run time any number reaches `filter_objects`, which refuses a non-integer with a ConfigError
    _CountArg = int | float

logger = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 300.0
"""Seconds one object's feature extraction may take (a 2M-face GLB takes well under a minute)."""


@dataclass(frozen=True, kw_only=True)
class FilterSummary:
    """Counts of a filter run."""

    total: int
    accepted: int


def _need_mesh_libraries() -> None:
    """Refuse the run when the `filter` extra's mesh libraries are missing.

    `extract_features` turns any loader error into a per-object rejection reason, which is right for
    a hostile file but not for a missing library: every object would be rejected and the run would
    "succeed". Checked once, in this process, before any worker starts.

    Raises:
        MissingDependencyError: trimesh or pymeshlab cannot be imported (the pip command included).
    """
    for module in ("trimesh", "pymeshlab"):
        try:
            __import__(module)
        except ImportError as exc:
            raise missing_extra(module, "filter") from exc


def filter_objects(
    src: str | Path,
    out: str | Path,
    *,
    rules_path: str | Path | None = None,
    classifier_path: str | Path | None = None,
    threshold: float = 0.5,
    workers: _CountArg = 1,
    timeout_s: float | int | None = DEFAULT_TIMEOUT_S,
    annotations_path: str | Path | None = None,
    max_worker_memory_mb: _CountArg = DEFAULT_MAX_WORKER_MEMORY_MB,
) -> FilterSummary:
    """Filter a folder of objects (or an Objaverse-style cache) and write the JSONL manifest.

    Args:
        src: folder of mesh files, or an Objaverse-style cache (`glbs/<group>/<uid>.glb` at, in or
            one level below `src`; its `annotations.json[.gz]` or `metadata/*.json[.gz]` are read).
        out: output `.jsonl` (written atomically).
        rules_path: JSON of `FilterRules` fields, or None for the defaults.
        classifier_path: folder of a trained classifier, or None (rules only).
        threshold: minimum classifier score to accept.
        workers: feature-extraction processes.
        timeout_s: seconds one object's features may take before it is rejected with
            "timeout after N s" (its worker is killed and replaced); None for no limit.
        annotations_path: an Objaverse annotation JSON (uid -> annotation, optionally gzipped) to use
            instead of the cache's own; object ids must be the uids.
        max_worker_memory_mb: MiB of address space one object may add to its worker before it is
            rejected with "worker exceeded memory cap of N MB" (Linux); 0 for no cap.

    Returns:
        Counts of objects and accepted objects.

    Raises:
        ConfigError: `workers` < 1, `timeout_s` not a positive number, `max_worker_memory_mb` < 0, or
            annotation rules without any annotations.
        InputError: no objects, or a malformed annotation file.
        MissingDependencyError: trimesh or pymeshlab (the `filter` extra) is not installed.
    """
    if not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"`workers`={workers!r} must be an integer >= 1 (`--workers`).")
    cap = max_worker_memory_mb
    if isinstance(cap, bool) or not isinstance(cap, int) or cap < 0:
        raise ConfigError(
            f"`max_worker_memory_mb`={cap!r} must be an integer >= 0 (`--max-worker-memory-mb`); "
            "0 disables the cap."
        )
    if timeout_s is not None and not (isinstance(timeout_s, int | float) and timeout_s > 0):
        raise ConfigError(
            f"`timeout_s`={timeout_s!r} must be a number of seconds > 0 (`--timeout`), "
            "or None for no limit."
        )
    if timeout_s is not None and not math.isfinite(timeout_s):
        timeout_s = None
    if cap > 0 and not memory_cap_supported():
        logger.warning("`--max-worker-memory-mb` needs Linux: filter workers run without a cap")
        cap = 0
    rules = FilterRules.from_json(rules_path) if rules_path is not None else FilterRules()
    classifier = QualityClassifier.load(classifier_path) if classifier_path is not None else None
    pairs, annotations = _objects_and_annotations(Path(src), annotations_path)
    if annotations is None and rules.uses_annotations():
        raise ConfigError(
            f"`rules`={str(rules_path)!r} sets annotation rules, but `src`={str(src)!r} has no "
            "annotations; pass `--annotations PATH` or an Objaverse cache with annotations.json[.gz] "
            "or metadata/*.json.gz."
        )
    annotated = {oid: (annotations or {}).get(oid) for oid, _ in pairs}
    first = {oid: rules.evaluate_annotation(annotated[oid]) for oid, _ in pairs}
    to_load = [(oid, p) for oid, p in pairs if all(o.passed for o in first[oid])]
    if to_load:
        _need_mesh_libraries()  # else every object would be rejected "not installed", exit 0
    options = {"max_file_mb": rules.max_file_mb, "max_faces": rules.max_faces}
    # Looked up at call time so tests can stand in a hostile extractor (it must be importable).
    features = extract_isolated(
        to_load,
        extract_features,
        workers=workers,
        timeout_s=timeout_s,
        options=options,
        memory_cap_mb=cap,
    )
    lines, accepted = [], 0
    for oid, path in pairs:
        feats = features.get(oid)  # None: rejected by its annotation, never loaded
        if feats is None and all(o.passed for o in first[oid]):  # internal: never accept unseen
            raise RuntimeError(f"internal error: no features came back for {oid!r}")
        outcomes = first[oid] + (rules.evaluate(feats) if feats is not None else [])
        reasons = [o.reason for o in outcomes if not o.passed]
        score = None
        if classifier is not None and feats is not None and feats.error is None:
            score = classifier.score(feats)
            if score < threshold:
                reasons.append(f"classifier score {score:.3f} < {threshold}")
        decision = "reject" if reasons else "accept"
        accepted += decision == "accept"
        annotation = annotated[oid]
        row = {
            "object_id": oid,
            "path": str(Path(path).resolve()),
            "decision": decision,
            "reasons": reasons,
            "score": score,
            "features": None if feats is None else feats.to_json(),
            "rules": [dataclasses.asdict(o) for o in outcomes],
            "annotation": None if annotation is None else annotation.to_json(),
        }
        lines.append(json.dumps(row, allow_nan=False, default=_json_default))
    atomic_write_text(Path(out), "\n".join(lines) + "\n")
    return FilterSummary(total=len(pairs), accepted=accepted)


def _objects_and_annotations(
    src: Path, annotations_path: str | Path | None
) -> tuple[list[tuple[str, Path]], dict[str, ObjaverseAnnotation] | None]:
    """`(object_id, path)` pairs and, where any are given or found, the annotations by uid."""
    glbs = find_objaverse_glbs(src)
    pairs = scan_objects(src) if glbs is None else scan_objaverse(glbs)
    if annotations_path is not None:
        files: tuple[Path, ...] = (Path(annotations_path),)
    elif glbs is not None:
        files = find_annotation_files(glbs.parent, src)
        if not files:
            logger.warning(
                "Objaverse cache %s has no annotations.json[.gz] or metadata/*.json.gz: "
                "objects are filtered on geometry only",
                glbs.parent,
            )
    else:
        files = ()
    if not files:
        return pairs, None
    annotations = read_annotations(files, {oid for oid, _ in pairs})
    missing = len(pairs) - len(annotations)
    if missing:
        logger.warning("%d of %d objects have no annotation entry", missing, len(pairs))
    return pairs, annotations


def _json_default(value: object) -> object:
    return str(value)
