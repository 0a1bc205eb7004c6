"""Ranking metrics from ``QueryResult.scores``: average precision and inverse rank.

Both are threshold-free: they judge the order the scores put the map's items in, which is
what a robot choosing where to go first uses. Only presence queries are ranked (an absent
object has no relevant item).

- **Average precision** (per query): items ranked by score (unlabelled and excluded items
  left out); ``AP = sum_k P(k) * rel(k) / n_relevant``, the area under the
  precision-recall curve without interpolation (scikit-learn's
  ``average_precision_score``). Ties share their block's precision. A random order scores
  the class share.
- **Inverse rank** (OpenLex3D, ``compute_query_inverse_rank`` in
  ``openlex3d/core/metric.py``): OpenLex3D ranks predicted *objects* by their similarity
  to the query, takes for each ground-truth object the rank of its best-matching
  prediction (IoU above a threshold), subtracts the number of ground-truth objects found
  before it (so finding all k objects at ranks 1..k scores 1 each) and averages
  ``1 / rank`` over the ground-truth objects (0 when not found). This function is one
  query's value; OpenLex3D's summary pools the objects of all queries, where
  :func:`~quash_plugins.evaluation.metrics.macro_mean` averages queries.
  A dense map has no predicted objects, so we use the map's **segments**: connected
  components of one ground-truth label (:func:`label_segments`), i.e. an oracle
  segmentation, each scored by the **mean** item score inside it. The ground-truth
  objects of a query are the segments of its label. Without top-k or a threshold, every
  object is found at some rank; ``max_rank`` (default None) turns ranks beyond it into 0,
  like OpenLex3D's top-k cut.

Examples
--------
>>> import numpy as np
>>> s = np.array([0.9, 0.8, 0.1, 0.7])
>>> t = np.array([True, False, False, True])
>>> round(average_precision(s, t), 3)
0.833
>>> seg = np.array([0, 1, 2, 3])
>>> inverse_rank(s, seg, t)   # objects 0 and 3 at ranks 1 and 3 -> adjusted 1 and 2
0.75
"""

from __future__ import annotations

import numpy as np


def average_precision(scores, truth, valid=None) -> float | None:
    """AP of ``scores`` for ``truth`` over the ``valid`` items; None when nothing is true."""
    s = np.asarray(scores, np.float64)
    t = np.asarray(truth, bool)
    if valid is not None:
        v = np.asarray(valid, bool)
        s, t = s[v], t[v]
    n_pos = int(t.sum())
    if n_pos == 0:
        return None
    order = np.argsort(-s, kind="stable")
    s, t = s[order], t[order]
    # one step per distinct score (ties share the precision at the end of their block)
    last = np.r_[np.flatnonzero(np.diff(s) != 0), len(s) - 1]
    tp = np.cumsum(t)[last]
    fp = (last + 1) - tp
    precision = tp / (tp + fp)
    recall_step = np.diff(np.r_[0, tp]) / n_pos
    return float(np.sum(precision * recall_step))


def inverse_rank(scores, segments, truth, valid=None, max_rank: int | None = None) -> float | None:
    """OpenLex3D's inverse rank over oracle segments (see the module docstring)."""
    s = np.asarray(scores, np.float64)
    seg = np.asarray(segments, np.int64)
    t = np.asarray(truth, bool)
    keep = seg >= 0
    if valid is not None:
        keep &= np.asarray(valid, bool)
    s, seg, t = s[keep], seg[keep], t[keep]
    if not t.any():
        return None
    ids, inv = np.unique(seg, return_inverse=True)
    sums = np.bincount(inv, weights=s)
    counts = np.bincount(inv)
    mean = sums / counts
    is_gt = np.bincount(inv, weights=t.astype(float)) > counts / 2
    order = np.argsort(-mean, kind="stable")
    rank = np.empty(len(ids), np.int64)
    rank[order] = np.arange(1, len(ids) + 1)
    gt_ranks = np.sort(rank[is_gt])
    adjusted = gt_ranks - np.arange(len(gt_ranks))
    inv_r = 1.0 / adjusted
    if max_rank is not None:
        inv_r[gt_ranks > max_rank] = 0.0
    return float(inv_r.mean())


def label_segments(labels, lmap) -> np.ndarray | None:
    """Ground-truth objects for :func:`inverse_rank`: the connected components of each
    label's items (26-connected voxels, points within the linking radius, 8-connected
    pixels of one frame; :class:`~quash_plugins.engine.topology.MapTopology`); -1 for
    unlabelled items. None when the map has no neighbourhood (no grid, positions or
    frames)."""
    from ..engine.topology import MapTopology

    topo = lmap if isinstance(lmap, MapTopology) else MapTopology(lmap)
    if topo.kind is None:
        return None
    labels = np.asarray(labels)
    seg = np.full(len(labels), -1, np.int64)
    nxt = 0
    for li in np.unique(labels[labels >= 0]):
        mask = labels == li
        for members in topo.components(mask):
            seg[members] = nxt
            nxt += 1
    return seg
