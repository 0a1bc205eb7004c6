"""Any scikit-learn estimator, by dotted path, as a QuASH classifier."""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
from sklearn.base import clone

from ..core.interfaces import Classifier
from ._params import (
    ClassifierParamError,
    check_finite_rows,
    iter_blocks,
    map_rows,
    piecewise_display,
    training_set,
)


def _import_estimator(path: Any) -> type:
    who = "sklearn"
    if not isinstance(path, str) or "." not in path:
        raise ClassifierParamError(
            f"{who}: parameter 'estimator' must be a dotted path such as "
            f"'sklearn.neighbors.KNeighborsClassifier'; got {path!r}."
        )
    module, _, name = path.rpartition(".")
    try:
        obj = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise ClassifierParamError(
            f"{who}: cannot import estimator {path!r} ({type(exc).__name__}: {exc})."
        ) from exc
    if not isinstance(obj, type):
        raise ClassifierParamError(f"{who}: {path!r} is not a class.")
    missing = [m for m in ("fit", "get_params") if not hasattr(obj, m)]
    if missing:
        raise ClassifierParamError(
            f"{who}: {path!r} is not a scikit-learn estimator (it lacks {', '.join(missing)})."
        )
    if not (hasattr(obj, "decision_function") or hasattr(obj, "predict_proba")):
        raise ClassifierParamError(
            f"{who}: {path!r} has neither decision_function nor predict_proba, so it "
            "cannot score map items. Pick a classifier that has one of them."
        )
    return obj


class SklearnClassifier(Classifier):
    """Wraps any scikit-learn classifier named by its dotted path.

    ``decision_function`` is the estimator's own ``decision_function`` (sign arranged
    so that > 0 means the positive class), or ``predict_proba[:, positive] - 0.5`` when
    it has none. Map rows are passed in blocks of ``block_rows``.

    Parameters
    ----------
    estimator
        Dotted path, e.g. ``"sklearn.neighbors.KNeighborsClassifier"``.
    params
        Keyword arguments for the estimator; unknown ones are rejected.
    block_rows
        Rows per call into the estimator (bounds its memory).
    """

    def __init__(
        self,
        estimator: str = "sklearn.linear_model.LogisticRegression",
        params: dict[str, Any] | None = None,
        block_rows: int = 65536,
    ) -> None:
        self.estimator = estimator
        self.params = params
        self.block_rows = block_rows

    def check_params(self) -> None:
        """Import the estimator and check ``params`` and ``block_rows`` without fitting."""
        self._build()

    def _build(self) -> Any:
        cls = _import_estimator(self.estimator)
        params = self.params or {}
        if not isinstance(params, dict):
            raise ClassifierParamError(f"sklearn: 'params' must be a mapping; got {params!r}.")
        try:
            est = cls()
            known = est.get_params(deep=False)
            unknown = [k for k in params if k not in known]
            if unknown:
                raise ClassifierParamError(
                    f"sklearn: {self.estimator} does not accept parameter {unknown[0]!r}. "
                    f"Accepted: {', '.join(sorted(known))}."
                )
            est.set_params(**params)
        except (TypeError, ValueError) as exc:
            if isinstance(exc, ClassifierParamError):
                raise
            raise ClassifierParamError(f"sklearn: cannot build {self.estimator}: {exc}") from exc
        if not isinstance(self.block_rows, int) or self.block_rows < 1:
            raise ClassifierParamError("sklearn: 'block_rows' must be a positive integer.")
        return est

    def fit(self, X: np.ndarray, y: np.ndarray) -> SklearnClassifier:
        est = self._build()
        X, y = training_set(self, "sklearn", X, y)
        self.estimator_ = clone(est).fit(X, y)
        self.positive_index_ = int(np.flatnonzero(np.asarray(self.estimator_.classes_) == 1)[0])
        self.uses_proba_ = not hasattr(self.estimator_, "decision_function")
        return self

    def _block_scores(self, block: np.ndarray) -> np.ndarray:
        est = self.estimator_
        pos = self.positive_index_
        if self.uses_proba_:
            return est.predict_proba(block)[:, pos] - 0.5
        d = np.asarray(est.decision_function(block))
        if d.ndim == 2:
            d = d[:, pos]
        elif pos == 0:
            d = -d
        return d

    def decision_function(self, E: Any) -> np.ndarray:
        """``(N,)`` float32 scores, > 0 for the positive class; ``E`` is read in blocks."""
        E = map_rows(self, "sklearn", E)
        out = np.empty(len(E), dtype=np.float32)
        for start, stop, block in iter_blocks(E, self.block_rows):
            check_finite_rows("sklearn", block, offset=start)
            out[start:stop] = self._block_scores(block)
        return out

    def display_scores(self, scores: np.ndarray, threshold: float = 0.0) -> np.ndarray:
        """``predict_proba`` when that is what scores are (cut 0.5 + threshold), else logistic."""
        if getattr(self, "uses_proba_", False):
            return piecewise_display(np.asarray(scores) + 0.5, 0.5 + threshold)
        return super().display_scores(scores, threshold)
