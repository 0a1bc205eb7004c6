"""Writing query results to files."""

from __future__ import annotations

import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_write
from ..core.types import QueryResult

#: The arrays of a results file, as :func:`write_results_npz` writes them.
RESULT_ARRAYS = ("queries", "masks", "scores", "display_scores")


def is_results_npz(path: str | Path) -> bool:
    """True when ``path`` is a results file written by :func:`write_results_npz`.

    Such a file may be replaced by a new result without ``--force``; anything else (a
    map, a file of the user's) may not.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    return names == {f"{a}.npy" for a in RESULT_ARRAYS}


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
