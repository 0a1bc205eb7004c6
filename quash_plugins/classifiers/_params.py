"""Shared helpers of the built-in classifiers: parameter errors, unit rows, display maps."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np

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
