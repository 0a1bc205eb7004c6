"""Evaluation: queryability metrics, the proxy scene, the demo and the ablation runner.

Nothing here imports torch or matplotlib at module level.
"""

from __future__ import annotations

from .metrics import absence_score, macro_mean, query_metrics, valid_items
from .plot import plot_precision_recall
from .report import DEFAULT_EXCLUDE, EvalReport, evaluate, report_markdown

__all__ = [
    "DEFAULT_EXCLUDE",
    "EvalReport",
    "absence_score",
    "evaluate",
    "macro_mean",
    "plot_precision_recall",
    "query_metrics",
    "report_markdown",
    "valid_items",
]
