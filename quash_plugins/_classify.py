"""One chunked pass over a map's embeddings, shared by every query being answered."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from .types import LatentMap

log = logging.getLogger(__name__)


def _extra_bytes_per_row(classifiers: Sequence[Any]) -> int:
    """Per-row bytes of a classifier's intermediates (e.g. the (rows, n_support) kernel)."""
    total = 0
    for clf in classifiers:
        width = getattr(clf, "working_set_width_", None)
        if width is None:
            sv = getattr(clf, "support_vectors_", None)
            width = len(sv) if sv is not None else 8
        total = max(total, 4 * int(width))
    return total + 16


def classify_local(
    lmap: LatentMap,
    classifiers: Sequence[Any],
    chunk_bytes: int = 256 * 2**20,
    progress: Any = None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Run every fitted classifier over ``lmap`` in one pass of row chunks.

    Returns one ``(N,)`` float32 score vector per classifier and the ``(N,)`` bool
    ``observed`` mask (False for zero rows, which never match). Memory stays bounded by
    ``chunk_bytes`` whatever N is.
    """
    n = lmap.n
    rows = lmap.chunk_rows(chunk_bytes, _extra_bytes_per_row(classifiers))
    scores = [np.empty(n, dtype=np.float32) for _ in classifiers]
    observed = np.empty(n, dtype=bool)
    # Several fitted SVMs share one GEMM per block (their support vectors stacked).
    from .classifiers import stack_classifiers

    stack, stacked = stack_classifiers(list(classifiers), chunk_bytes)
    for start, stop, block in lmap.iter_chunks(rows):
        sq = np.einsum("ij,ij->i", block, block)
        observed[start:stop] = sq > 0
        if stack is not None:
            multi = stack.evaluate(block, sq=None if stack.unit else sq, unit=stack.unit)
            for j, i in enumerate(stacked):
                scores[i][start:stop] = multi[:, j]
        for i, (out, clf) in enumerate(zip(scores, classifiers)):
            if i not in stacked:
                out[start:stop] = np.asarray(clf.decision_function(block), dtype=np.float32).ravel()
        if progress is not None:
            progress(stop - start)
    return scores, observed
