"""One chunked pass over a map's embeddings, shared by every query being answered."""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.kernels import KernelExpansion, stack_expansions
from ..core.maps import map_read_error
from ..core.types import LatentMap

log = logging.getLogger(__name__)


def kernel_expansions(classifiers: Sequence[Any]) -> list[KernelExpansion | None]:
    """Each classifier's kernel expansion, or None where it implements no stacking."""
    out = []
    for clf in classifiers:
        expand = getattr(clf, "kernel_expansion", None)
        out.append(expand() if callable(expand) else None)
    return out


def extra_bytes_per_row(classifiers: Sequence[Any]) -> int:
    """Per-row bytes of a classifier's intermediates (e.g. the (rows, n_support) kernel)."""
    total = 0
    for clf in classifiers:
        width = getattr(clf, "working_set_width_", None)
        if width is None:
            sv = getattr(clf, "support_vectors_", None)
            width = len(sv) if sv is not None else 8
        total = max(total, 4 * int(width))
    return total + 16


class BlockScorer:
    """Scores prepared float32 blocks for every fitted classifier of one pass.

    The single block computation of the engine, used by the in-memory pass
    (:func:`classify_local`) and by every Dask chunk task, so both give the same numbers.
    Classifiers that implement the ``StackableClassifier`` protocol share one GEMM per
    block; the others are called one by one. Pickles as its classifiers (Dask ships it to
    each worker once).
    """

    def __init__(self, classifiers: Sequence[Any], chunk_bytes: int = 256 * 2**20) -> None:
        self.classifiers = list(classifiers)
        self.chunk_bytes = int(chunk_bytes)
        self.stack, self.stacked = stack_expansions(
            kernel_expansions(self.classifiers), self.chunk_bytes
        )

    def __len__(self) -> int:
        return len(self.classifiers)

    def score(self, block: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``(rows, Q + 1)`` float32: each classifier's raw score, then ``observed`` (0/1).

        ``block`` is an already prepared ``(rows, D)`` float32 block (see
        :func:`~quash_plugins.core.types.prepare_block`); zero rows are unobserved.
        """
        q = len(self.classifiers)
        if out is None:
            out = np.empty((block.shape[0], q + 1), dtype=np.float32)
        sq = np.einsum("ij,ij->i", block, block)
        out[:, q] = sq > 0
        if self.stack is not None:
            multi = self.stack.evaluate(
                block, sq=None if self.stack.unit else sq, unit=self.stack.unit
            )
            out[:, self.stacked] = multi
        for i, clf in enumerate(self.classifiers):
            if i not in self.stacked:
                out[:, i] = np.asarray(clf.decision_function(block), dtype=np.float32).ravel()
        return out


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
    rows = lmap.chunk_rows(chunk_bytes, extra_bytes_per_row(classifiers))
    scorer = BlockScorer(classifiers, chunk_bytes)
    q = len(scorer)
    out = np.empty((q + 1, n), dtype=np.float32)  # one contiguous row per query
    for start, stop, block in read_blocks(lmap, rows):
        out[:, start:stop] = scorer.score(block).T
        if progress is not None:
            progress(stop - start)
    return [out[i] for i in range(q)], out[q] > 0


def read_blocks(lmap: LatentMap, rows: int) -> Iterator[tuple[int, int, np.ndarray]]:
    """:meth:`LatentMap.iter_chunks`, with a failure to read rows (a corrupt or unreadable
    chunk, a file gone) reported as a :class:`MapFormatError` naming the file and rows."""
    blocks = lmap.iter_chunks(rows)
    start = 0
    while True:
        try:
            start, stop, block = next(blocks)
        except StopIteration:
            return
        except QuashError:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure to read rows is the map's
            stop = min(lmap.n, start + rows)
            raise map_read_error(
                lmap.source.get("path", "the map"),
                exc,
                lmap.source.get("adapter"),
                f"rows {start}-{stop - 1} of the embeddings",
            ) from exc
        yield start, stop, block
        start = stop


#: Share of unobserved (all-zero) items above which a query warns about the map.
UNOBSERVED_WARNING = 0.5
_warned: set[tuple[str, int, int]] = set()


def warn_unobserved(lmap: LatentMap, observed: np.ndarray) -> None:
    """Warn (once per map) when all or most of ``lmap`` is unobserved (zero rows).

    Such items never match, so a map that is all zeros answers every query with nothing.
    A damaged store (a missing zarr chunk reads as zeros) looks the same.
    """
    n = int(observed.size)
    unobserved = n - int(np.count_nonzero(observed))
    if n == 0 or unobserved <= UNOBSERVED_WARNING * n:
        return
    where = str(lmap.source.get("path", "the map"))
    key = (where, n, unobserved)
    if key in _warned:
        return
    _warned.add(key)
    if unobserved == n:
        log.warning(
            "%s: every one of its %d items has an all-zero embedding (unobserved), so no "
            "query can match. The map is empty or damaged (a missing chunk or block reads "
            "as zeros).",
            where,
            n,
        )
    else:
        log.warning(
            "%s: %d of %d items (%.1f%%) have all-zero embeddings (unobserved) and never "
            "match. If the map should be observed there, it may be damaged.",
            where,
            unobserved,
            n,
            100.0 * unobserved / n,
        )
