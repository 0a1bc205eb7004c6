"""The peers' decision rules as scikit-learn estimators."""

from __future__ import annotations

import numpy as np

from ..interfaces import Classifier, check_training_set


def _unit(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float32)
    n = np.linalg.norm(a, axis=1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


class ContrastClassifier(Classifier):
    """VLMaps' rule: an item matches when it is closer (cosine) to a positive than to
    every negative.

    ``decision_function`` is ``max_p cos(x, p) - max_n cos(x, n)``. With the ``none``
    heuristic and negatives ``[other]`` this is VLMaps' argmax over ``[query, other]``.
    """

    def fit(self, X: np.ndarray, y: np.ndarray) -> ContrastClassifier:
        X, y = check_training_set(X, y)
        self.positives_ = _unit(X[y == 1])
        self.negatives_ = _unit(X[y == 0])
        self.classes_ = np.array([0, 1])
        return self

    def decision_function(self, E: np.ndarray) -> np.ndarray:
        E = np.asarray(E, dtype=np.float32)
        pos = (E @ self.positives_.T).max(axis=1)
        neg = (E @ self.negatives_.T).max(axis=1)
        return (pos - neg).astype(np.float32)
