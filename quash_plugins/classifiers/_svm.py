"""SVM classifiers (the paper's choice)."""

from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.svm import SVC

from ..interfaces import Classifier, check_training_set


class RbfSvmClassifier(Classifier):
    """SVC with an RBF kernel: the paper's default classifier.

    Parameters
    ----------
    C
        Regularisation strength.
    gamma
        ``"scale"``, ``"auto"`` or a positive float.
    class_weight
        ``None``, ``"balanced"`` or ``{0: w0, 1: w1}``.
    """

    def __init__(self, C: float = 1.0, gamma: Any = "scale", class_weight: Any = None) -> None:
        self.C = C
        self.gamma = gamma
        self.class_weight = class_weight

    def fit(self, X: np.ndarray, y: np.ndarray) -> RbfSvmClassifier:
        X, y = check_training_set(X, y)
        self.svc_ = SVC(kernel="rbf", C=self.C, gamma=self.gamma, class_weight=self.class_weight)
        self.svc_.fit(X, y)
        self.support_vectors_ = self.svc_.support_vectors_
        self.classes_ = self.svc_.classes_
        return self

    def decision_function(self, E: np.ndarray) -> np.ndarray:
        return self.svc_.decision_function(np.asarray(E, dtype=np.float32)).astype(np.float32)
