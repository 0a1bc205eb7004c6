"""Built-in classifiers: the paper's SVMs and every peer's decision rule.

All are scikit-learn estimators, so every method runs through the same pipeline and
evaluation. See ``docs/classifiers.md``.
"""

from __future__ import annotations

from ._baselines import (
    ContrastClassifier,
    CosineThresholdClassifier,
    LabelArgmaxClassifier,
    LerfRelevancyClassifier,
    NearestSampleClassifier,
)
from ._params import ClassifierParamError
from ._sklearn import SklearnClassifier
from ._svm import CosineSvmClassifier, RbfSvmClassifier

__all__ = [
    "ClassifierParamError",
    "ContrastClassifier",
    "CosineSvmClassifier",
    "CosineThresholdClassifier",
    "LabelArgmaxClassifier",
    "LerfRelevancyClassifier",
    "NearestSampleClassifier",
    "RbfSvmClassifier",
    "SklearnClassifier",
]
