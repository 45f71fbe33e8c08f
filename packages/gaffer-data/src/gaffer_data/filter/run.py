"""`gaffer-data filter`: features -> rules -> classifier score -> decision, one JSONL line per object.

Feature extraction runs in a pool of spawned subprocesses, so a loader that crashes the interpreter
(a segfault in a native mesh library) costs one object, recorded as rejected, never the run.
"""

import concurrent.futures
import dataclasses
import json
import logging
import multiprocessing
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from gaffer_data._atomic import atomic_write_text
from gaffer_data.filter.classifier import QualityClassifier
from gaffer_data.filter.features import ObjectFeatures, extract_features
from gaffer_data.filter.rules import FilterRules
from gaffer_data.recipes import scan_objects

logger = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class FilterSummary:
    """Counts of a filter run."""

    total: int
    accepted: int


def _run_pool(
    pairs: list[tuple[str, Path]],
    workers: int,
    rules: FilterRules,
    results: dict[str, ObjectFeatures],
) -> list[tuple[str, Path]]:
    """Extract features in a spawned process pool; return the objects lost to a broken pool."""
    crashed = []
    ctx = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
        futures = {
            pool.submit(
                extract_features,
                oid,
                path,
                max_file_mb=rules.max_file_mb,
                max_faces=rules.max_faces,
            ): (oid, path)
            for oid, path in pairs
        }
        for future in concurrent.futures.as_completed(futures):
            try:
                results[futures[future][0]] = future.result()
            except BrokenProcessPool:
                crashed.append(futures[future])
    return crashed


def _features_isolated(
    pairs: list[tuple[str, Path]], workers: int, rules: FilterRules
) -> dict[str, ObjectFeatures]:
    results: dict[str, ObjectFeatures] = {}
    # A crash breaks the whole pool and we cannot tell which object did it: retry each alone.
    for oid, path in _run_pool(pairs, workers, rules, results):
        if _run_pool([(oid, path)], 1, rules, results):
            logger.warning("%s: feature extraction crashed the process", oid)
            results[oid] = ObjectFeatures(
                object_id=oid, path=str(path), error="feature extraction crashed the process"
            )
    return results


def filter_objects(
    src: str | Path,
    out: str | Path,
    *,
    rules_path: str | Path | None = None,
    classifier_path: str | Path | None = None,
    threshold: float = 0.5,
    workers: int = 1,
) -> FilterSummary:
    """Filter a folder of objects and write the JSONL manifest.

    Args:
        src: folder of mesh files.
        out: output `.jsonl` (written atomically).
        rules_path: JSON of `FilterRules` fields, or None for the defaults.
        classifier_path: folder of a trained classifier, or None (rules only).
        threshold: minimum classifier score to accept.
        workers: feature-extraction processes.

    Returns:
        Counts of objects and accepted objects.
    """
    rules = FilterRules.from_json(rules_path) if rules_path is not None else FilterRules()
    classifier = QualityClassifier.load(classifier_path) if classifier_path is not None else None
    pairs = scan_objects(src)
    features = _features_isolated(pairs, workers, rules)
    lines, accepted = [], 0
    for oid, path in pairs:
        feats = features[oid]
        outcomes = rules.evaluate(feats)
        reasons = [o.reason for o in outcomes if not o.passed]
        score = None
        if classifier is not None and feats.error is None:
            score = classifier.score(feats)
            if score < threshold:
                reasons.append(f"classifier score {score:.3f} < {threshold}")
        decision = "reject" if reasons else "accept"
        accepted += decision == "accept"
        row = {
            "object_id": oid,
            "path": str(Path(path).resolve()),
            "decision": decision,
            "reasons": reasons,
            "score": score,
            "features": feats.to_json(),
            "rules": [dataclasses.asdict(o) for o in outcomes],
        }
        lines.append(json.dumps(row, allow_nan=False, default=_json_default))
    atomic_write_text(Path(out), "\n".join(lines) + "\n")
    return FilterSummary(total=len(pairs), accepted=accepted)


def _json_default(value: object) -> object:
    return str(value)
