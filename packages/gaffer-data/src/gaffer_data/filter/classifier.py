"""The learned quality classifier (paper §3.1: trained on a manually annotated subset).

A scikit-learn random forest over `ObjectFeatures.vector()`, trained from a CSV of `object_id,label`
(1 = good, 0 = bad) joined with a `gaffer-data filter` JSONL of features, reported with stratified
k-fold cross-validated accuracy, saved as `model.pkl` + `classifier.json` (schema, versions, metrics,
sha256 of the model). Pickles execute code when loaded: only load classifiers you trained or trust; the
loader checks the recorded sha256 first.
"""

import csv
import dataclasses
import json
import pickle
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gaffer_data._atomic import atomic_write, atomic_write_json
from gaffer_data._version import __version__
from gaffer_data.dataset.manifest import check_schema, read_json, sha256_file, utc_now
from gaffer_data.errors import ConfigError, InputError, IntegrityError, missing_extra
from gaffer_data.filter.features import NUMERIC_FEATURES, ObjectFeatures

CLASSIFIER_SCHEMA = "gaffer.quality_classifier"
CLASSIFIER_SCHEMA_VERSION = "1.0"


@dataclass(frozen=True, kw_only=True)
class ClassifierReport:
    """Training summary, also stored in `classifier.json`."""

    samples: int
    positives: int
    folds: int
    cv_accuracy_mean: float
    cv_accuracy_std: float
    feature_names: tuple[str, ...]
    sklearn_version: str
    producer_version: str


def read_labels(path: str | Path) -> dict[str, int]:
    """Read `object_id,label` rows (header required; label 0/1 or false/true).

    Raises:
        InputError: missing columns or bad labels.
    """
    labels: dict[str, int] = {}
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or not {"object_id", "label"} <= set(reader.fieldnames):
            raise InputError(f"`labels`={str(path)!r} needs a header with columns object_id,label.")
        for n, row in enumerate(reader, 2):
            text = row["label"].strip().lower()
            if text not in ("0", "1", "true", "false"):
                raise InputError(
                    f"`labels`={str(path)!r} line {n}: label {row['label']!r} is not 0/1."
                )
            labels[row["object_id"]] = int(text in ("1", "true"))
    return labels


def read_feature_records(path: str | Path) -> dict[str, ObjectFeatures]:
    """Features per object id from a `gaffer-data filter` JSONL manifest.

    Objects rejected by their annotation before loading have no features and are left out.
    """
    out = {}
    how = "pass the JSONL manifest `gaffer-data filter --out` wrote"
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"`features`={str(path)!r} could not be read ({exc}); {how}.") from exc
    for n, line in enumerate(lines, 1):
        if line.strip():
            try:
                row = json.loads(line)
                if row.get("features") is not None:
                    out[row["object_id"]] = ObjectFeatures.from_json(row["features"])
            except (json.JSONDecodeError, AttributeError, KeyError, TypeError, ValueError) as exc:
                raise InputError(
                    f"`features`={str(path)!r} line {n} is not a filter record ({exc}); {how}."
                ) from exc
    return out


def train_classifier(
    features: str | Path, labels: str | Path, out: str | Path, *, folds: int = 5, seed: int = 0
) -> ClassifierReport:
    """Train, cross-validate and save the quality classifier.

    Args:
        features: a `gaffer-data filter` JSONL (one line per object with its features).
        labels: CSV of `object_id,label`.
        out: folder for `model.pkl` and `classifier.json`.
        folds: stratified cross-validation folds.
        seed: random-forest and fold seed.

    Returns:
        The training report.

    Raises:
        InputError: fewer than `folds` examples of a class, or no labelled object has features.
        MissingDependencyError: scikit-learn is not installed.
    """
    try:
        import sklearn
        from sklearn.ensemble import RandomForestClassifier
        from sklearn.model_selection import StratifiedKFold, cross_val_score
    except ImportError as exc:
        raise missing_extra("sklearn", "filter") from exc
    feats = read_feature_records(features)
    label_map = read_labels(labels)
    ids = sorted(i for i in label_map if i in feats)
    if not ids:
        raise InputError(
            "no labelled object appears in `features`; label ids must match the filter's ids."
        )
    x = np.stack([feats[i].vector() for i in ids])
    y = np.array([label_map[i] for i in ids])
    counts = np.bincount(y, minlength=2)
    if counts.min() < folds or folds < 2:
        raise InputError(
            f"`folds`={folds} needs >= {folds} objects of each class (have {counts[0]} bad, {counts[1]} good); "
            "label more objects or lower `--folds` (>= 2)."
        )
    model = RandomForestClassifier(n_estimators=200, random_state=seed, class_weight="balanced")
    cv = StratifiedKFold(n_splits=folds, shuffle=True, random_state=seed)
    scores = cross_val_score(model, x, y, cv=cv, scoring="accuracy")
    model.fit(x, y)
    out = Path(out)
    model_path = out / "model.pkl"
    atomic_write(model_path, lambda tmp: tmp.write_bytes(pickle.dumps(model)))
    report = ClassifierReport(
        samples=len(ids),
        positives=int(counts[1]),
        folds=folds,
        cv_accuracy_mean=float(scores.mean()),
        cv_accuracy_std=float(scores.std()),
        feature_names=NUMERIC_FEATURES,
        sklearn_version=sklearn.__version__,
        producer_version=__version__,
    )
    atomic_write_json(
        out / "classifier.json",
        {
            "schema": CLASSIFIER_SCHEMA,
            "schema_version": CLASSIFIER_SCHEMA_VERSION,
            "producer": {"package": "gaffer-data", "version": __version__},
            "created_utc": utc_now(),
            "model": {
                "path": "model.pkl",
                "sha256": sha256_file(model_path),
                "class": "RandomForestClassifier",
            },
            "report": dataclasses.asdict(report),
        },
    )
    return report


@dataclass(frozen=True)
class QualityClassifier:
    """A loaded classifier: `score(features)` is the probability that an object is good."""

    model: object
    report: ClassifierReport

    @classmethod
    def load(cls, folder: str | Path) -> "QualityClassifier":
        """Load a classifier saved by `train_classifier`.

        Raises:
            SchemaVersionError: other schema or MAJOR version.
            IntegrityError: the model file does not match its recorded sha256.
            ConfigError: it was trained on other features.
        """
        folder = Path(folder)
        meta = read_json(folder / "classifier.json")
        check_schema(
            meta, schema=CLASSIFIER_SCHEMA, version=CLASSIFIER_SCHEMA_VERSION, where=f"`{folder}`"
        )
        model_path = folder / meta["model"]["path"]
        if not model_path.is_file() or sha256_file(model_path) != meta["model"]["sha256"]:
            raise IntegrityError(
                f"`{model_path}` is missing or differs from its recorded sha256; retrain it."
            )
        rep = meta["report"]
        report = ClassifierReport(**{**rep, "feature_names": tuple(rep["feature_names"])})
        if report.feature_names != NUMERIC_FEATURES:
            raise ConfigError(
                f"`{folder}` was trained on other features; retrain with this gaffer-data."
            )
        import sklearn

        if report.sklearn_version != sklearn.__version__:
            warnings.warn(
                f"`{folder}` was trained with scikit-learn {report.sklearn_version}, this is "
                f"{sklearn.__version__}; scores may differ slightly.",
                UserWarning,
                stacklevel=2,
            )
        model = pickle.loads(model_path.read_bytes())
        return cls(model=model, report=report)

    def score(self, features: ObjectFeatures) -> float:
        """Probability of the "good" class for one object."""
        proba = self.model.predict_proba(features.vector()[None, :])  # type: ignore[attr-defined]
        classes = list(self.model.classes_)  # type: ignore[attr-defined]
        return float(proba[0, classes.index(1)]) if 1 in classes else 0.0
