"""Queryability metrics (Pekkanen et al. 2025): per-query TP/FP/FN and their macro means.

Rules
-----
- Ground truth of a query label is ``labels == label_id``.
- **Unlabelled items** (``labels < 0``) and items whose label is **excluded** (``exclude``
  names such as ``void``, ``unlabeled``) are ignored: they count neither as TP nor FP.
- **A label of the map that no item carries** is not a presence query: it is scored as
  an absence query instead, and never enters the precision/recall/F1/IoU means (a label
  that is no name of the map is refused: ``evaluation.queries.match_labels``).
- Empty denominators: precision with no prediction is 0 (or 1 when there is also no
  ground truth); recall with no ground truth is 1 only when nothing was predicted.
- **Absence queries** score 1 when the mask is "empty": at most ``empty_tolerance``
  matched (counted) items. The default tolerance is 0, strictly nothing. The absence
  score of a method is the share of its absence queries with an empty mask.

Examples
--------
>>> import numpy as np

from .queries import label_key
>>> m = query_metrics(np.array([1, 1, 0, 0], bool), np.array([1, 0, 1, 0], bool))
>>> (m["tp"], m["fp"], m["fn"], round(m["f1"], 2))
(1, 1, 1, 0.5)
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .queries import label_key

METRICS = ("precision", "recall", "f1", "iou")
#: Threshold-free metrics from the scores (:mod:`quash_plugins.evaluation.ranking`).
RANKING = ("ap", "inv_rank")


def query_metrics(
    mask: np.ndarray, truth: np.ndarray, valid: np.ndarray | None = None
) -> dict[str, Any]:
    """Precision, recall, F1 and IoU of one query.

    Parameters
    ----------
    mask
        ``(N,) bool`` predicted matches.
    truth
        ``(N,) bool`` ground truth.
    valid
        ``(N,) bool`` items that count (unlabelled and excluded items are False).
    """
    mask = np.asarray(mask, bool)
    truth = np.asarray(truth, bool)
    if valid is not None:
        valid = np.asarray(valid, bool)
        mask, truth = mask & valid, truth & valid
    tp = int(np.count_nonzero(mask & truth))
    fp = int(np.count_nonzero(mask & ~truth))
    fn = int(np.count_nonzero(~mask & truth))
    pred, gt = tp + fp, tp + fn
    precision = tp / pred if pred else (1.0 if gt == 0 else 0.0)
    recall = tp / gt if gt else (1.0 if pred == 0 else 0.0)
    f1 = 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    union = tp + fp + fn
    iou = tp / union if union else 1.0
    return {
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "iou": iou,
        "n_true": gt,
        "n_pred": pred,
    }


def macro_mean(per_query: dict[str, dict[str, Any]]) -> dict[str, float | None]:
    """The unweighted mean of each metric over queries (None for all when there are none:
    nothing was scored, which a 0 would misreport as a method that found nothing).

    The ranking metrics (:data:`RANKING`) are averaged over the queries that have them
    (None: undefined, e.g. no neighbourhood for the inverse rank); None when none has.
    Every key of :data:`METRICS` and :data:`RANKING` is always there.
    """
    if not per_query:
        return dict.fromkeys((*METRICS, *RANKING))
    out = {k: float(np.mean([q[k] for q in per_query.values()])) for k in METRICS}
    for k in RANKING:
        vals = [q[k] for q in per_query.values() if q.get(k) is not None]
        out[k] = float(np.mean(vals)) if vals else None
    return out


def valid_items(
    labels: np.ndarray, label_names: Sequence[str] | None, exclude: Iterable[str] = ()
) -> np.ndarray:
    """``(N,) bool``: items with a label >= 0 whose name is not in ``exclude`` (ignoring
    case, spacing and underscores, as a query's label is matched: ``void`` drops ``Void``).
    """
    labels = np.asarray(labels)
    valid = labels >= 0
    names = list(label_names or [])
    dropped = {label_key(e) for e in exclude}
    drop = [i for i, n in enumerate(names) if label_key(n) in dropped]
    if drop:
        valid &= ~np.isin(labels, drop)
    return valid


def absence_score(
    masks: dict[str, np.ndarray], valid: np.ndarray | None = None, empty_tolerance: int = 0
) -> dict[str, Any]:
    """Score absence queries: the share whose mask matches at most ``empty_tolerance`` items.

    Returns ``{"score": share or None, "empty_tolerance": t, "per_query": {q: {"matched": n,
    "empty": bool}}}``; ``score`` is None when there are no absence queries.
    """
    per = {}
    for q, mask in masks.items():
        m = np.asarray(mask, bool)
        if valid is not None:
            m = m & valid
        n = int(np.count_nonzero(m))
        per[q] = {"matched": n, "empty": n <= empty_tolerance}
    score = float(np.mean([p["empty"] for p in per.values()])) if per else None
    return {"score": score, "empty_tolerance": int(empty_tolerance), "per_query": per}
