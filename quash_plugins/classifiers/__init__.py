"""Built-in classifiers: the paper's SVMs and every peer's decision rule.

All are scikit-learn estimators, so every method runs through the same pipeline and
evaluation.
"""

from __future__ import annotations

from ._baselines import ContrastClassifier
from ._svm import RbfSvmClassifier

__all__ = ["ContrastClassifier", "RbfSvmClassifier"]
