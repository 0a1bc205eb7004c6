"""Shared helpers of the built-in classifiers: parameter errors, scikit-learn input
validation (training set and map rows), unit rows, display maps."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from scipy import sparse
from sklearn.utils.multiclass import check_classification_targets, type_of_target
from sklearn.utils.validation import check_is_fitted, validate_data

from ..core.errors import ConfigError


class ClassifierParamError(ConfigError, ValueError):
    """A classifier parameter is invalid.

    Both a :class:`~quash_plugins.core.errors.ConfigError` (the CLI prints it as a one-line
    user error) and a :class:`ValueError` (what scikit-learn code expects).
    """


def check_choice(who: str, field: str, value: Any, choices: tuple[Any, ...]) -> Any:
    """Return ``value`` when it is one of ``choices``; raise naming the field otherwise."""
    if value not in choices:
        known = ", ".join(repr(c) for c in choices)
        raise ClassifierParamError(f"{who}: parameter {field!r} is {value!r}; use one of {known}.")
    return value


def check_positive(who: str, field: str, value: Any, allow_zero: bool = False) -> float:
    """Return ``value`` as float when it is a finite positive real number."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
    if ok:
        v = float(value)
        ok = np.isfinite(v) and (v > 0 or (allow_zero and v == 0))
    if not ok:
        what = "a non-negative" if allow_zero else "a positive"
        raise ClassifierParamError(
            f"{who}: parameter {field!r} must be {what} number; got {value!r}."
        )
    return float(value)


def check_class_weight(who: str, value: Any) -> Any:
    """``None``, ``"balanced"`` or ``{0: w0, 1: w1}`` with positive weights."""
    if value is None or value == "balanced":
        return value
    if isinstance(value, dict):
        keys = {int(k) if str(k).lstrip("-").isdigit() else k for k in value}
        if keys <= {0, 1}:
            for k, w in value.items():
                check_positive(who, f"class_weight[{k!r}]", w)
            return {int(k): float(w) for k, w in value.items()}
    raise ClassifierParamError(
        f"{who}: parameter 'class_weight' is {value!r}; use null, 'balanced' or "
        "{0: weight_of_negatives, 1: weight_of_positives}."
    )


def training_set(estimator: Any, who: str, X: Any, y: Any) -> tuple[np.ndarray, np.ndarray]:
    """Validate a training set the scikit-learn way; return ``X`` and ``y`` as 0/1.

    ``X`` must be dense, real and finite, ``(n, D)``; ``y`` must hold exactly two
    classes. Sets ``estimator.classes_`` (sorted labels: ``classes_[1]`` is the positive
    class, 1 in QuASH's ``y``) and ``estimator.n_features_in_``.

    Returns
    -------
    X
        ``(n, D)`` float64 or float32 (float32 input stays float32).
    y
        ``(n,)`` int64, 1 where ``y == classes_[1]``.
    """
    if sparse.issparse(X):
        raise TypeError(
            f"{who}: sparse input is not supported; pass a dense array (X.toarray()) of "
            "text embeddings."
        )
    X, y = validate_data(estimator, X, y, dtype=(np.float64, np.float32), y_numeric=False)
    check_classification_targets(y)
    classes = np.unique(y)
    if len(classes) < 2:
        raise ValueError(
            f"{who}: y has one class ({classes.tolist()}); fit needs both classes: "
            "positives (1) and negatives (0)."
        )
    if len(classes) > 2:
        raise ValueError(
            f"{who}: Only binary classification is supported. The type of the target is "
            f"{type_of_target(y)!r} with {len(classes)} classes; use 1 for positives and "
            "0 for negatives."
        )
    estimator.classes_ = classes
    return X, (y == classes[1]).astype(np.int64)


def map_rows(estimator: Any, who: str, E: Any) -> Any:
    """Check the map rows given to ``decision_function``; return them ready to slice.

    Raises :class:`~sklearn.exceptions.NotFittedError` before ``fit``, :class:`TypeError`
    for sparse input and :class:`ValueError` for complex values, a wrong number of
    dimensions or of features. Arrays that slice by rows (numpy, memmap, h5py, zarr,
    torch) are returned as they are, so a large map is never copied whole; anything
    else (a list) becomes a numpy array. NaN and Inf are checked block by block by the
    caller (:func:`check_finite_block` or :func:`check_finite_rows`).
    """
    check_is_fitted(
        estimator,
        msg=f"{who}: this %(name)s is not fitted yet; call fit(X, y) before "
        "decision_function or predict.",
    )
    if sparse.issparse(E):
        raise TypeError(
            f"{who}: sparse input is not supported; pass the map's embeddings as a dense "
            "array (E.toarray(), or a numpy, memmap, h5py or zarr array)."
        )
    if not (hasattr(E, "shape") and hasattr(E, "dtype")):
        E = np.asarray(E)
    kind = np.dtype(E.dtype).kind if isinstance(E.dtype, np.dtype) else None
    if kind == "c":
        raise ValueError(f"{who}: Complex data not supported; map embeddings must be real.")
    if kind == "O":
        E = np.asarray(E, dtype=np.float64)
    shape = tuple(E.shape)
    if len(shape) != 2:
        raise ValueError(
            f"{who}: expected a 2-D array of map embeddings (n_items, "
            f"{estimator.n_features_in_}); got shape {shape}. Reshape your data: "
            "E.reshape(1, -1) for a single item."
        )
    if shape[1] != estimator.n_features_in_:
        raise ValueError(
            f"{who}: X has {shape[1]} features, but {type(estimator).__name__} is expecting "
            f"{estimator.n_features_in_} features as input. The map's embeddings and the "
            "encoder's must have the same dimension: is the config's encoder the one the "
            "map was built with?"
        )
    return E


def check_finite_block(who: str, x: np.ndarray, start: int, sq_norms: np.ndarray) -> None:
    """Raise when the float32 block ``x`` (rows ``start:``) holds NaN or Inf.

    ``sq_norms`` are the block's squared row norms, which the caller computed anyway: a
    row is finite when its norm is (the exact test runs only on rows whose square
    overflowed or was not finite), so the check costs nothing on a clean map.
    """
    bad = ~np.isfinite(sq_norms)
    if bad.any():
        rows = np.flatnonzero(bad)
        for r in rows:
            if not np.isfinite(x[r]).all():
                raise ValueError(
                    f"{who}: Input X contains NaN or infinity (map row {start + int(r)}); "
                    "map embeddings must be finite."
                )


def check_finite_rows(who: str, E: Any, rows: int = 65536, offset: int = 0) -> None:
    """Raise when ``E`` holds NaN or Inf, reading it block by block (never copied whole).

    The test per block is one float64 sum (finite data cannot overflow it); only a block
    whose sum is not finite is searched for the bad row. ``offset`` is added to the row
    number in the message (when ``E`` is itself a block of a map).
    """
    mod = type(E).__module__.split(".")[0]
    if mod == "torch":
        import torch

        if not bool(torch.isfinite(E).all()):
            raise ValueError(
                f"{who}: Input X contains NaN or infinity; map embeddings must be finite."
            )
        return
    for start in range(0, len(E), max(1, int(rows))):
        x = np.asarray(E[start : start + rows])
        if x.dtype.kind not in "fc" or np.isfinite(np.sum(x, dtype=np.float64)):
            continue
        bad = ~np.isfinite(x)
        if bad.any():
            row = offset + start + int(np.argwhere(bad)[0][0])
            raise ValueError(
                f"{who}: Input X contains NaN or infinity (map row {row}); map embeddings "
                "must be finite."
            )


def unit_rows(a: np.ndarray) -> np.ndarray:
    """``(n, D)`` float32 copy with L2-unit rows; zero rows stay zero."""
    a = np.asarray(a, dtype=np.float32)
    n = np.linalg.norm(a, axis=1, keepdims=True)
    return np.divide(a, n, out=np.zeros_like(a), where=n > 0)


def iter_blocks(E: Any, rows: int):
    """Yield ``(start, stop, block)`` with ``block`` a float32 ``(r, D)`` array.

    Float16 (or any other dtype) input is up-cast block by block, never whole.
    """
    n = len(E)
    for start in range(0, n, max(1, int(rows))):
        stop = min(n, start + rows)
        yield start, stop, np.asarray(E[start:stop], dtype=np.float32)


def piecewise_display(p: np.ndarray, cut: float) -> np.ndarray:
    """Map a natural probability ``p`` in [0, 1] to [0, 1] with ``cut`` sent to 0.5.

    Linear on ``[0, cut]`` and on ``[cut, 1]``: with the default cut of 0.5 the display
    score *is* the probability; a moved threshold moves the 0.5 point with it.
    """
    p = np.clip(np.asarray(p, dtype=np.float64), 0.0, 1.0)
    c = float(np.clip(cut, 1e-6, 1.0 - 1e-6))
    low = 0.5 * p / c
    high = 0.5 + 0.5 * (p - c) / (1.0 - c)
    return np.where(p <= c, low, high).astype(np.float32)
