"""Writing query results to files."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_write
from ..core.types import QueryResult


def write_results_npz(path: str | Path, results: Sequence[QueryResult]) -> Path:
    """Write ``queries (Q,) str``, ``masks (Q, N) bool``, ``scores (Q, N) float32`` atomically."""
    path = Path(path)
    queries = np.asarray([r.query for r in results], dtype=str)
    masks = np.stack([r.mask for r in results]).astype(bool)
    scores = np.stack([r.scores for r in results]).astype(np.float32)
    display = np.stack([r.display_scores for r in results]).astype(np.float32)
    with atomic_write(path, suffix=".npz") as tmp:
        np.savez(tmp, queries=queries, masks=masks, scores=scores, display_scores=display)
    return path
