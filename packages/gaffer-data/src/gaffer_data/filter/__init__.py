"""Object filtering: features (trimesh, pymeshlab, glTF materials), typed rules, a learned classifier,
Objaverse-style cache input with annotation rules, and isolated workers under time and memory caps.

Never imports bpy (pymeshlab and bpy cannot share a process).
"""

from gaffer_data.filter.classifier import ClassifierReport, QualityClassifier, train_classifier
from gaffer_data.filter.features import NUMERIC_FEATURES, ObjectFeatures, extract_features
from gaffer_data.filter.memory_cap import DEFAULT_MAX_WORKER_MEMORY_MB
from gaffer_data.filter.objaverse import ObjaverseAnnotation, read_annotations
from gaffer_data.filter.rules import FilterRules, RuleOutcome
from gaffer_data.filter.run import FilterSummary, filter_objects

__all__ = [
    "DEFAULT_MAX_WORKER_MEMORY_MB",
    "NUMERIC_FEATURES",
    "ClassifierReport",
    "FilterRules",
    "FilterSummary",
    "ObjaverseAnnotation",
    "ObjectFeatures",
    "QualityClassifier",
    "RuleOutcome",
    "extract_features",
    "filter_objects",
    "read_annotations",
    "train_classifier",
]
