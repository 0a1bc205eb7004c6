"""One fused pass over a map's rows, shared by every query being answered.

:class:`BlockScorer` is the single block computation of the engine: the in-memory pass
(:func:`classify_local`) and every Dask chunk task
(:mod:`quash_plugins.engine.dask_executor`) call it on the same blocks, so both executors
give the same numbers, bit for bit. Each cache-sized block of rows (2048 by default) is
handled start to finish by one worker thread:

1. **Read as stored, never written.** float32 rows are used in place (a map may be a
   read-only memory map, or the caller's own array); float16 rows are converted into a
   reused float32 buffer (:func:`~quash_plugins.core.cpu.half_to_float`, exact and
   about twice numpy's cast; torch's cast, twice faster again, when torch is already
   imported, unless ``QUASH_HALF_CAST=numpy``); other dtypes are cast into the same
   buffer.
2. **One GEMM** ``x @ W``: ``W`` holds the columns of every fitted classifier that
   implements the ``StackableClassifier`` protocol (kernel SVMs, stacked whatever
   ``backend`` they were fitted with: the pass chooses where it runs) followed by the
   label vectors of every ``CosineClassifier`` (the peers' cosine rules).
3. **Squared row norms** ``|x|^2``, read from cache after the GEMM. They give the
   observed mask (``|x|^2 > 0``) and the NaN/Inf check: a NaN or Inf entry makes its
   row's squared norm NaN or Inf (squares cannot cancel), so only a block whose largest
   norm is not finite gets the exact ``np.isfinite`` search (which names the row; a
   huge but finite row is not an error).
4. **The map is never normalised.** ``x/|x| . v = (x . v) / |x|``: the small
   ``(rows, W)`` GEMM result is scaled instead (see
   :class:`~quash_plugins.core.kernels.StackEpilogue`), then each stacked SVM's
   epilogue and each rule's reduction run on their own columns.

Any other classifier (a wrapped scikit-learn estimator, a plugin) gets the block as
float32, normalised into a buffer of its own when the map asks for it, one call at a
time. Worker threads take blocks dynamically, each with a single-threaded BLAS
(:func:`~quash_plugins.core.cpu.blas_single_thread`).
"""

from __future__ import annotations

import itertools
import logging
import os
import sys
import threading
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np

from ..core.cpu import HALF_SQ_LIMIT, blas_single_thread, cpu_threads, half_to_float, sq_norms
from ..core.errors import MapFormatError, QuashError
from ..core.expansions import CosineExpansion, KernelExpansion
from ..core.kernels import KernelStack, StackEpilogue
from ..core.maps import map_read_error
from ..core.once import first_time
from ..core.types import LatentMap
from .stored_chunks import warn_small_chunks, warn_stored_chunks

log = logging.getLogger(__name__)

#: Rows per block (1024 to 4096 measured within noise of each other at D = 384).
DEFAULT_BLOCK_ROWS = 2048


def kernel_expansions(classifiers: Sequence[Any]) -> list[KernelExpansion | None]:
    """Each classifier's kernel expansion (``StackableClassifier``), or None."""
    out = []
    for clf in classifiers:
        expand = getattr(clf, "kernel_expansion", None)
        out.append(expand() if callable(expand) else None)
    return out


def cosine_expansions(classifiers: Sequence[Any]) -> list[CosineExpansion | None]:
    """Each classifier's cosine expansion (``CosineClassifier``), or None."""
    out = []
    for clf in classifiers:
        expand = getattr(clf, "cosine_expansion", None)
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


def half_cast() -> Callable[[np.ndarray, np.ndarray], np.ndarray] | None:
    """torch's float16 to float32 copy (F16C/AVX-512, about twice :func:`half_to_float`)
    when torch is *already imported* (every torch text encoder imports it), else None.
    ``QUASH_HALF_CAST=numpy`` turns it off. Both casts are exact."""
    if "torch" not in sys.modules or os.environ.get("QUASH_HALF_CAST") == "numpy":
        return None
    import torch

    def cast(src: np.ndarray, out: np.ndarray) -> np.ndarray:
        with warnings.catch_warnings():  # a read-only map: torch only reads it here
            warnings.filterwarnings("ignore", message="The given NumPy array is not writable")
            torch.from_numpy(out).copy_(torch.from_numpy(src))
        return out

    return cast


def scoring_copy(clf: Any) -> Any:
    """``clf`` as a pass needs it: a shallow copy without the fitted attributes its class
    names in ``_unused_when_scoring`` (scikit-learn's own model, a training set), or
    ``clf`` itself when there are none.

    A pickled :class:`BlockScorer` (a Dask pass: one graph task that every worker
    receives) holds these copies, so the graph carries what scoring reads (the support
    vectors, the label vectors), not every array the classifier keeps. The copy scores
    and postprocesses exactly as ``clf`` does; ``clf`` itself is unchanged.
    """
    state = getattr(clf, "__dict__", None)
    drop = [k for k in getattr(type(clf), "_unused_when_scoring", ()) if state and k in state]
    if not drop:
        return clf
    out = object.__new__(type(clf))
    out.__dict__.update({k: v for k, v in state.items() if k not in drop})
    return out


class _Workspace:
    """One worker's reused buffers."""

    def __init__(self, rows: int, dim: int, width: int, cast: bool, prep: bool) -> None:
        self.buf = np.empty((rows, dim), np.float32) if cast else None
        self.G = np.empty((rows, max(1, width)), np.float32)
        self.prep = np.empty((rows, dim), np.float32) if prep else None
        self.half_cast = half_cast()


class BlockScorer:
    """Scores of ``classifiers`` for blocks of map rows: one fused pass per block.

    Parameters
    ----------
    classifiers
        Fitted classifiers; output ``i`` is ``classifiers[i]``.
    chunk_bytes
        The pass's working-set budget (sizes the stack's own blocks for direct calls).
    block_rows
        Rows per block (default :data:`DEFAULT_BLOCK_ROWS`).

    Attributes
    ----------
    stacked
        Indices of the classifiers whose kernel expansions share the GEMM (those with
        the ``unit_rows`` of the first one; any others are called one by one).
    rules
        ``(index, first column, end column)`` of every cosine expansion in ``W``.
    others
        Indices of the classifiers called through ``decision_function``.

    Pickles as its classifiers (Dask ships it to each worker once), each without what
    scoring never reads (:func:`scoring_copy`, and the classifiers' own derived arrays);
    the GEMM's columns are rebuilt where it is unpickled.
    """

    def __init__(
        self,
        classifiers: Sequence[Any],
        chunk_bytes: int = 256 * 2**20,
        block_rows: int | None = None,
    ) -> None:
        self.classifiers = list(classifiers)
        self.chunk_bytes = int(chunk_bytes)
        self.block_rows = int(block_rows or DEFAULT_BLOCK_ROWS)
        self._build()

    def __getstate__(self) -> dict[str, Any]:
        state = {k: self.__dict__[k] for k in ("classifiers", "chunk_bytes", "block_rows")}
        state["classifiers"] = [scoring_copy(c) for c in self.classifiers]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._build()

    def __len__(self) -> int:
        return len(self.classifiers)

    def _build(self) -> None:
        kexp = kernel_expansions(self.classifiers)
        idx = [i for i, e in enumerate(kexp) if e is not None]
        self.unit = bool(idx) and bool(kexp[idx[0]].unit_rows)
        self.stacked = [i for i in idx if bool(kexp[i].unit_rows) == self.unit]
        self.stack: KernelStack | None = None
        cols: list[np.ndarray] = []
        col = 0
        if self.stacked:
            parts = [kexp[i].part for i in self.stacked]
            self.stack = KernelStack(parts, "numpy", "cpu", self.chunk_bytes)
            cols.append(self.stack.columns)
            col = self.stack.width
        self.rule_start = col
        self.rules: list[tuple[int, int, int]] = []
        self._reduce: dict[int, Callable[[np.ndarray], np.ndarray]] = {}
        stacked = set(self.stacked)
        for i, e in enumerate(cosine_expansions(self.classifiers)):
            if e is None or i in stacked:
                continue
            cols.append(np.ascontiguousarray(np.asarray(e.labels, np.float32).T))
            self.rules.append((i, col, col + e.width))
            self._reduce[i] = e.reduce
            col += e.width
        done = stacked | {i for i, _, _ in self.rules}
        self.others = [i for i in range(len(self.classifiers)) if i not in done]
        self.width = col
        self.W = np.ascontiguousarray(np.concatenate(cols, axis=1)) if cols else None
        self._epilogues: dict[bool, StackEpilogue] = {}
        self._lock = threading.Lock()

    def epilogue(self, normalize: bool) -> StackEpilogue | None:
        """The stacked SVMs' epilogue for a map read with or without ``normalize``."""
        if self.stack is None:
            return None
        ep = self._epilogues.get(bool(normalize))
        if ep is None:
            ep = self._epilogues[bool(normalize)] = self.stack.epilogue(normalize, self.unit)
        return ep

    def workspace(self, rows: int, dtype: Any, dim: int, normalize: bool) -> _Workspace:
        cast = np.dtype(dtype) != np.float32
        return _Workspace(rows, dim, self.width, cast, bool(self.others) and normalize)

    # ------------------------------------------------------------------ one block
    def _as_float32(self, xs: np.ndarray, ws: _Workspace) -> tuple[np.ndarray, np.float32]:
        """float32 rows of ``xs`` (``xs`` itself when float32) and the ``|x|^2`` limit
        under which the block is certainly finite."""
        if xs.dtype == np.float32:
            return xs, np.float32(np.inf)
        x = ws.buf[: len(xs)]
        if xs.dtype == np.float16 and xs.flags.c_contiguous:
            if ws.half_cast is not None:  # NaN/Inf kept as they are: the plain limit
                return ws.half_cast(xs, x), np.float32(np.inf)
            return half_to_float(xs, x), HALF_SQ_LIMIT
        np.copyto(x, xs, casting="unsafe")
        return x, np.float32(np.inf)

    @staticmethod
    def _check_rows(xs: np.ndarray, sq: np.ndarray, start: int, source: dict[str, Any]) -> None:
        """Exact NaN/Inf check of a block whose squared norms were not all below the
        limit; squared norms that overflowed float32 are recomputed in float64."""
        finite = np.isfinite(xs)
        if not finite.all():
            bad = int(np.argwhere(~finite)[0][0]) + start
            path = source.get("path")
            where = f" in {path}" if path else ""
            raise MapFormatError(
                f"Field 'embeddings'{where} contains NaN or Inf (first at row {bad}). "
                "Fix or drop those rows before querying."
            )
        big = ~(sq < np.float32(np.inf))
        if big.any():
            x64 = np.asarray(xs[big], np.float64)
            sq[big] = np.einsum("ij,ij->i", x64, x64).astype(np.float32)

    def score_block(
        self,
        xs: np.ndarray,
        start: int,
        outs: Sequence[np.ndarray],
        observed: np.ndarray,
        ws: _Workspace,
        normalize: bool,
        source: dict[str, Any] | None = None,
    ) -> None:
        """Score rows ``xs`` (as stored, never written) into ``outs[i]`` and ``observed``.

        ``start`` is the map row of ``xs[0]`` (for error messages).
        """
        x, limit = self._as_float32(xs, ws)
        rows = len(x)
        G = None
        with np.errstate(over="ignore", invalid="ignore"):  # checked just below
            if self.W is not None:
                # the GEMM first: it streams the rows in; |x|^2 then reads them from cache
                G = ws.G[:rows]
                np.matmul(x, self.W, out=G)
            sq = sq_norms(x)
            if not sq.max() < limit:  # NaN propagates through max
                self._check_rows(xs, sq, start, source or {})
        obs = np.greater(sq, 0, out=observed)
        ep = self.epilogue(normalize)
        inv = None
        if self.rules or (ep is not None and ep.needs_inv) or (self.others and normalize):
            inv = np.sqrt(sq)
            np.divide(1.0, inv, out=inv, where=obs)  # zero rows keep sqrt(0) = 0
        if G is not None:
            if ep is not None:
                R = ep.apply(G[:, : self.rule_start], sq, inv, obs)
                for j, i in enumerate(self.stacked):
                    outs[i][...] = R[:, j]
            if self.rules:
                C = G[:, self.rule_start :]
                C *= inv[:, None]
                for i, c0, c1 in self.rules:
                    c = C[:, c0 - self.rule_start : c1 - self.rule_start]
                    outs[i][...] = self._reduce[i](c)
        if self.others:
            if normalize:
                xp = np.multiply(x, inv[:, None], out=ws.prep[:rows])
            else:
                xp = x.view()
                xp.flags.writeable = False  # may be the map itself
            with self._lock:  # a plugin need not be thread-safe
                for i in self.others:
                    r = self.classifiers[i].decision_function(xp)
                    outs[i][...] = np.asarray(r, dtype=np.float32).ravel()

    # ------------------------------------------------------------------ many blocks
    def run(
        self,
        E: np.ndarray,
        outs: Sequence[np.ndarray],
        observed: np.ndarray,
        *,
        normalize: bool,
        source: dict[str, Any] | None = None,
        offset: int = 0,
        chunk_rows: int | None = None,
        threads: int | None = None,
        progress: Any = None,
    ) -> None:
        """Score every row of the in-memory ``E`` (ndarray or memmap, any float dtype).

        ``outs[i]`` and ``observed`` are ``(len(E),)``; ``offset`` is the map row of
        ``E[0]``. Blocks start at every multiple of ``chunk_rows`` (default: all of
        ``E``) and every :attr:`block_rows` after it, so the in-memory pass and a Dask
        task on the chunk of the same rows score the very same blocks. ``threads``
        worker threads (default: the CPU cores this process may use) take blocks in
        turn; ``progress(rows)`` is called after each block, one call at a time.
        """
        n = len(E)
        if n == 0:
            return
        step = max(1, int(chunk_rows or n))
        spans = [
            (a, min(c + step, n, a + self.block_rows))
            for c in range(0, n, step)
            for a in range(c, min(c + step, n), self.block_rows)
        ]
        workers = max(1, min(threads or cpu_threads(), len(spans)))
        counter = itertools.count()  # next() is atomic under the GIL: dynamic balancing
        plock = threading.Lock()
        src = source or {}

        def work() -> None:
            ws = self.workspace(min(self.block_rows, n), E.dtype, E.shape[1], normalize)
            while (k := next(counter)) < len(spans):
                a, b = spans[k]
                part = [o[a:b] for o in outs]
                self.score_block(E[a:b], offset + a, part, observed[a:b], ws, normalize, src)
                if progress is not None:
                    with plock:
                        progress(b - a)

        with blas_single_thread():
            if workers == 1:
                work()
                return
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(workers) as pool:
                for job in [pool.submit(work) for _ in range(workers)]:
                    job.result()

    def score(
        self,
        block: Any,
        start: int = 0,
        normalize: bool = False,
        source: dict[str, Any] | None = None,
        threads: int = 1,
    ) -> np.ndarray:
        """``(rows, Q + 1)`` float32 for one chunk of rows as stored: each classifier's
        raw score, then ``observed`` (0/1). What a Dask chunk task computes.

        The rows are scored C-ordered, as :func:`read_blocks` hands them to the local
        pass: a chunk in Fortran order (per-image features in the (1, D, h, w) layout
        are transposed views) would round its GEMM differently."""
        x = np.ascontiguousarray(block)
        q = len(self.classifiers)
        out = np.empty((x.shape[0], q + 1), dtype=np.float32)
        observed = np.empty(x.shape[0], dtype=bool)
        outs = [out[:, i] for i in range(q)]
        opts = {"normalize": normalize, "source": source, "offset": start, "threads": threads}
        self.run(x, outs, observed, **opts)
        out[:, q] = observed
        return out


def classify_local(
    lmap: LatentMap,
    classifiers: Sequence[Any],
    chunk_bytes: int = 256 * 2**20,
    progress: Any = None,
    threads: int | None = None,
    block_rows: int | None = None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Run every fitted classifier over ``lmap`` in one pass of row blocks.

    Returns one ``(N,)`` float32 score vector per classifier and the ``(N,)`` bool
    ``observed`` mask (False for zero rows, which never match). An in-memory map
    (ndarray, memmap) is scored where it lies, block by block; any other array-like
    (h5py, zarr, dask, an adapter's row view) is read in chunks of
    ``lmap.chunk_rows(chunk_bytes, ...)`` rows *as stored*, so memory stays bounded by
    ``chunk_bytes`` whatever N is. The map is never written.
    """
    n = lmap.n
    rows = lmap.chunk_rows(chunk_bytes, extra_bytes_per_row(classifiers))
    warn_small_chunks(lmap, rows, chunk_bytes)
    scorer = BlockScorer(classifiers, chunk_bytes, block_rows)
    q = len(scorer)
    out = np.empty((q, n), dtype=np.float32)  # one contiguous row per query
    outs = [out[i] for i in range(q)]
    observed = np.empty(n, dtype=bool)
    E = lmap.embeddings
    opts = {"normalize": bool(lmap.normalize), "source": lmap.source, "threads": threads}
    if isinstance(E, np.ndarray):
        scorer.run(E, outs, observed, chunk_rows=rows, progress=progress, **opts)
        return outs, observed
    warn_stored_chunks(lmap, rows, chunk_bytes)
    for start, stop, chunk in read_blocks(lmap, rows):
        part = [o[start:stop] for o in outs]
        scorer.run(chunk, part, observed[start:stop], offset=start, progress=progress, **opts)
    return outs, observed


def read_blocks(lmap: LatentMap, rows: int) -> Iterator[tuple[int, int, np.ndarray]]:
    """``(start, stop, chunk)``: the map's rows in chunks of ``rows``, as stored (a
    C-contiguous array, never cast), with a failure to read rows (a corrupt or unreadable
    chunk, a file gone) reported as a :class:`MapFormatError` naming the file and rows."""
    E = lmap.embeddings
    for start in range(0, lmap.n, rows):
        stop = min(lmap.n, start + rows)
        try:
            chunk = np.ascontiguousarray(E[start:stop])
        except QuashError:
            raise
        except Exception as exc:  # noqa: BLE001 - any failure to read rows is the map's
            raise map_read_error(
                lmap.source.get("path", "the map"),
                exc,
                lmap.source.get("adapter"),
                f"rows {start}-{stop - 1} of the embeddings{_chunk_keys(E, start, stop)}",
            ) from exc
        yield start, stop, chunk


def _chunk_keys(E: Any, start: int, stop: int, most: int = 4) -> str:
    """`` (zarr chunk embeddings/c/2/0)``: the chunks of a zarr array that fail to read
    in rows ``start:stop``, each tried alone (the files to check or copy again); ``""``
    for anything else. Only called after a read failed."""
    chunks, meta = getattr(E, "chunks", None), getattr(E, "metadata", None)
    encode = getattr(meta, "encode_chunk_key", None)
    if encode is None or not chunks or len(chunks) != 2 or len(getattr(E, "shape", ())) != 2:
        return ""
    name = str(getattr(E, "path", "") or "").strip("/")
    bad: list[str] = []
    try:
        for r in range(start // chunks[0], (stop - 1) // chunks[0] + 1):
            for c in range(-(-E.shape[1] // chunks[1])):
                try:
                    E[r * chunks[0] : (r + 1) * chunks[0], c * chunks[1] : (c + 1) * chunks[1]]
                except Exception:  # noqa: BLE001 - this chunk is one that fails
                    bad.append(f"{name}/{encode((r, c))}" if name else encode((r, c)))
    except Exception:  # noqa: BLE001 - naming the chunk must never hide the real error
        return ""
    if not bad:
        return ""
    more = " ..." if len(bad) > most else ""
    return f" (zarr chunk{'s' if len(bad) > 1 else ''} {', '.join(bad[:most])}{more})"


#: Share of unobserved (all-zero) items above which a query warns about the map.
UNOBSERVED_WARNING = 0.5


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
    if not first_time(("unobserved", where, n, unobserved)):
        return
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
