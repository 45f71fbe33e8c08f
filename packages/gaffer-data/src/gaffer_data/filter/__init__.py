"""Object filtering: features (trimesh, pymeshlab, glTF materials), typed rules, a learned classifier.

Never imports bpy (pymeshlab and bpy cannot share a process).
"""

from gaffer_data.filter.classifier import ClassifierReport, QualityClassifier, train_classifier
from gaffer_data.filter.features import NUMERIC_FEATURES, ObjectFeatures, extract_features
from gaffer_data.filter.memory_cap import DEFAULT_MAX_WORKER_MEMORY_MB
from gaffer_data.filter.rules import FilterRules, RuleOutcome
from gaffer_data.filter.run import FilterSummary, filter_objects

__all__ = [
    "DEFAULT_MAX_WORKER_MEMORY_MB",
    "NUMERIC_FEATURES",
    "ClassifierReport",
    "FilterRules",
    "FilterSummary",
    "ObjectFeatures",
    "QualityClassifier",
    "RuleOutcome",
    "extract_features",
    "filter_objects",
    "train_classifier",
]
