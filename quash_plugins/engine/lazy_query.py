"""Lazy query results: masks and scores as dask arrays, written to zarr chunk by chunk.

Map-level postprocessing (``Classifier.postprocess_scores``) needs the whole score
vector. Here it is done with dask reductions: a classifier whose postprocess depends only
on the minimum and maximum of the observed scores (identity, min-max normalisation,
clipping) is applied block by block with those two values; any other postprocess is
detected by a probe and falls back to one ``(N,)`` float32 vector per such query.

A config with ``refine`` or ``presence`` needs more than a graph of blocks: the
refinement re-fits on the first pass's whole mask, and the presence check splits the
final mask into connected components. :meth:`LazyQuery.to_zarr` then answers the
queries in groups with ``Quash._answer`` (the very code of ``Quash.query_many``) and
writes each group's rows: it holds ``(N,)`` vectors per query of the group
(:data:`BYTES_PER_QUERY_ITEM`), never the embeddings.
"""

from __future__ import annotations

import logging
import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_dir, refuse_own_input
from ..core.layout import map_layout
from ..core.types import QuerySet, check_query
from .answer import _describe, classifier_words
from .classify import BlockScorer
from .dask_client import current_client, require_dask, require_zarr
from .dask_executor import compute, scores_graph, ship
from .results import is_results_zarr

log = logging.getLogger(__name__)

#: Bytes per map item per query that :meth:`LazyQuery.to_zarr` sizes a group of queries
#: by when the config has ``refine`` or ``presence``: the held scores (float32), mask
#: (bool) and display scores (float32), 9 bytes, plus the refinement pass's new float32
#: scores while the first pass's are still held.
BYTES_PER_QUERY_ITEM = 13

#: The config steps that only :meth:`LazyQuery.to_zarr` applies (see :func:`query_lazy`).
STEPS = ("refine", "presence")


def group_size(n: int, budget_bytes: int) -> int:
    """Queries per group: as many as keep ``(group, n)`` vectors of
    :data:`BYTES_PER_QUERY_ITEM` bytes under ``budget_bytes``, and at least one."""
    return max(1, int(budget_bytes) // (BYTES_PER_QUERY_ITEM * max(1, int(n))))


def postprocess_kind(clf: Any) -> str:
    """``"identity"``, ``"minmax"`` (depends only on min and max) or ``"global"``."""
    from ..core.interfaces import Classifier

    method = getattr(type(clf), "postprocess_scores", None)
    if method is None or method is Classifier.postprocess_scores:
        return "identity"
    rng = np.random.default_rng(7)
    v = rng.normal(size=257).astype(np.float32) * 3
    try:
        full = np.asarray(clf.postprocess_scores(v.copy()), np.float32)
        part = v[100:140]
        sub = np.concatenate([[v.min(), v.max()], part]).astype(np.float32)
        got = np.asarray(clf.postprocess_scores(sub), np.float32)[2:]
        v2 = np.concatenate([v, [v.mean()] * 50]).astype(np.float32)
        shifted = np.asarray(clf.postprocess_scores(v2), np.float32)[100:140]
    except Exception:  # noqa: BLE001 - an odd postprocess takes the safe path
        return "global"
    ok = np.allclose(full[100:140], got, atol=1e-6) and np.allclose(
        full[100:140], shifted, atol=1e-6
    )
    return "minmax" if ok else "global"


def _minmax_post(clf: Any, values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    if values.size == 0:
        return values
    sub = np.concatenate([np.float32([lo, hi]), values]).astype(np.float32)
    return np.asarray(clf.postprocess_scores(sub), np.float32)[2:]


def _global_post(clf: Any, raw: np.ndarray, observed: np.ndarray) -> np.ndarray:
    out = np.array(raw, dtype=np.float32)
    if observed.any():
        out[observed] = np.asarray(clf.postprocess_scores(out[observed]), np.float32)
    return out


def _minmax_block(
    col: np.ndarray,
    observed: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    fitted: BlockScorer,
    i: int,
) -> np.ndarray:
    """One query's postprocessed block; NaN marks unobserved rows."""
    out = np.full(col.shape, np.nan, dtype=np.float32)
    out[observed] = _minmax_post(fitted.classifiers[i], col[observed], float(lo[0]), float(hi[0]))
    return out


def _global_block(col: np.ndarray, observed: np.ndarray, fitted: BlockScorer, i: int) -> np.ndarray:
    out = _global_post(fitted.classifiers[i], col, observed)
    out[~observed] = np.nan
    return out


def _store_rows(block: np.ndarray, zarr_array: Any, block_info: Any = None) -> np.ndarray:
    """Write one row block of raw scores into ``zarr_array``; ``[rows written]``."""
    a, b = block_info[0]["array-location"][0] if block_info else (0, len(block))
    zarr_array[a:b] = block
    return np.array([b - a], np.int64)


def _rows_written(part: np.ndarray) -> int:
    return int(np.sum(part))


def _check_written(zraw: Any, path: Path) -> None:
    """Every chunk of ``zraw`` is in the store this process sees, or a usage error.

    A worker that does not share this process's file system writes its chunks into a
    folder of its own at the same path: the store here would read them as missing."""
    from ..core.errors import UsageError

    have, want = zraw.nchunks_initialized, zraw.nchunks
    if have < want:
        raise UsageError(
            f"{path}: {want - have} of {want} chunks of the results the Dask workers wrote "
            "are not in the store this process writes: the workers do not see "
            f"{path.parent} as this process does. Write the results to storage the "
            "workers share (the same path on every machine), or leave out --scheduler "
            "to run a local cluster (see docs/scale.md)."
        )


class LazyQuery:
    """The lazy answer to several queries over one map (see :func:`query_lazy`).

    Attributes
    ----------
    raw
        ``(N, Q + 1)`` float32 dask array: raw decision values, last column observed.
    skipped
        The config's steps (``"refine"``, ``"presence"``) that :attr:`scores`,
        :attr:`masks` and :meth:`compute` leave out; :meth:`to_zarr` applies them.
    """

    def __init__(
        self,
        querysets,
        classifiers,
        raw,
        threshold,
        client,
        held,
        lmap,
        *,
        quash: Any = None,
        pending: list[Any] | None = None,
        pass_client: Any = None,
    ) -> None:
        self.querysets: list[QuerySet] = querysets
        self.classifiers = classifiers
        self.raw = raw
        self.threshold = float(threshold)
        self.client = client
        self.lmap = lmap
        self._held = held
        self.kinds = [postprocess_kind(c) for c in classifiers]
        self._quash = quash
        self._pending = list(pending or [])
        self._pass_client = pass_client
        self.skipped = [k for k in STEPS if getattr(quash, k, None) is not None]

    @property
    def queries(self) -> list[str]:
        return [qs.query for qs in self.querysets]

    @property
    def observed(self) -> Any:
        """``(N,)`` bool dask array: False for zero rows."""
        return self.raw[:, len(self.classifiers)] > 0

    def _post(self, raw: Any) -> Any:
        """``(N, Q)`` float32 dask array of postprocessed scores, NaN where unobserved.

        Min/max statistics are dask reductions passed to every block as one-element
        arrays; a ``"global"`` postprocess sees its whole ``(N,)`` column in one task.
        """
        da = require_dask()
        q = len(self.classifiers)
        obs = raw[:, q] > 0
        cols = []
        for i, kind in enumerate(self.kinds):
            col = raw[:, i]
            if kind == "identity":
                cols.append(da.where(obs, col, np.float32(np.nan)))
            elif kind == "minmax":
                masked = da.where(obs, col, np.float32(np.nan))
                lo, hi = da.nanmin(masked).reshape(1), da.nanmax(masked).reshape(1)
                cols.append(
                    da.map_blocks(
                        _minmax_block,
                        col,
                        obs,
                        lo,
                        hi,
                        self._held,
                        i,
                        dtype=np.float32,
                        meta=np.empty((0,), np.float32),
                    )
                )
            else:
                whole = da.map_blocks(
                    _global_block,
                    col.rechunk(-1),
                    obs.rechunk(-1),
                    self._held,
                    i,
                    dtype=np.float32,
                    meta=np.empty((0,), np.float32),
                )
                cols.append(whole.rechunk(col.chunks))
        # One chunk across the queries: the zarr stores are chunked (Q, rows), and two
        # tasks writing parts of one zarr chunk without a lock would overwrite each other.
        return da.stack(cols, axis=1).rechunk({1: -1}).astype(np.float32)

    def _final(self, post: Any, floors: Any) -> tuple[Any, Any]:
        """``(Q, N)`` scores (unobserved rows at ``floors``) and masks."""
        da = require_dask()
        scores = da.where(da.isnan(post), floors[None, :], post).astype(np.float32)
        masks = post > np.float32(self.threshold)
        return scores.T, masks.T

    def _floors(self, post: Any) -> Any:
        """Per-query score given to unobserved rows: below every observed score and the
        threshold, as in :meth:`Quash.query_many`."""
        da = require_dask()
        thr = np.float32(self.threshold)
        if post.shape[0] == 0:  # an empty map: nothing to reduce over
            return da.full((post.shape[1],), thr - np.float32(1.0), dtype=np.float32)
        m = da.nanmin(post, axis=0)
        return (da.where(da.isnan(m), thr, da.minimum(m, thr)) - np.float32(1.0)).astype(np.float32)

    def _lazy(self) -> tuple[Any, Any]:
        if self.skipped:
            steps = " and ".join(self.skipped)
            warnings.warn(
                f"LazyQuery.scores, .masks and .compute() are the first pass only: the "
                f"config's {steps} step{'s are' if len(self.skipped) > 1 else ' is'} not "
                "applied, so absent objects may match. LazyQuery.to_zarr (query_to_zarr, "
                "--out *.zarr) applies them.",
                stacklevel=3,
            )
        post = self._post(self.raw)
        return self._final(post, self._floors(post))

    @property
    def scores(self) -> Any:
        """``(Q, N)`` float32 dask array, as :attr:`QueryResult.scores` (postprocessed)
        of the first pass: without the :attr:`skipped` steps (a warning names them)."""
        return self._lazy()[0]

    @property
    def masks(self) -> Any:
        """``(Q, N)`` bool dask array, as :attr:`QueryResult.mask` of the first pass:
        without the :attr:`skipped` steps (a warning names them)."""
        return self._lazy()[1]

    def compute(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(scores (Q, N) float32, masks (Q, N) bool, observed (N,) bool)`` in memory,
        of the first pass (see :attr:`scores`)."""
        scores, masks = self._lazy()
        return tuple(np.asarray(x) for x in compute(self.client, scores, masks, self.observed))

    def to_zarr(
        self,
        path: str | Path,
        overwrite: bool = True,
        group_mb: float | None = None,
        up: str | None = None,
    ) -> Path:
        """Write ``scores``, ``masks`` and ``observed`` to a zarr store, atomically.

        An existing ``path`` is replaced (with ``overwrite``) only when it is empty or a
        results store this method wrote: any other folder, a converted map's zarr store
        included, is refused (:class:`~quash_plugins.core.errors.UsageError`).

        The arrays equal :meth:`Quash.query_many`'s ``scores`` and ``mask``. Without
        ``refine`` and ``presence`` in the config: three passes, each bounded by the
        chunk size: the map pass writes raw scores (``4 (Q + 1)`` bytes per row) into the
        store; the two small passes over them compute the map-level statistics and write
        the final arrays. With either step: see :meth:`_write_answered`; ``group_mb``
        bounds the ``(group, N)`` vectors held at once (default: the Quash's
        ``chunk_mb``).

        The store's attributes (:meth:`_attrs`) include the up axis of the map's
        positions, ``up``: ``up`` when given (``quash query --up``), else the one the
        map's ``source`` records; none when neither says (``+z`` is then assumed), as
        ``write_results_npz`` records it.
        """
        if self.skipped and self._pending:
            return self._write_answered(path, overwrite, group_mb, up)
        from ..core.progress import progress

        zarr = require_zarr()
        da = require_dask()
        path = Path(path).expanduser()
        refuse_own_input(path, self.lmap.source, folder=True)
        n, q = self.raw.shape[0], len(self.classifiers)
        rows = max(1, self.raw.chunks[0][0])  # an empty map has one chunk of 0 rows
        # the temporary store by its absolute path: the workers write its chunks, and a
        # worker's working directory need not be this process's (a scheduler of its own)
        with atomic_dir(
            path.absolute(), overwrite=overwrite, replaceable=is_results_zarr, kind="results store"
        ) as tmp:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            # NaN fill: every written chunk is stored (the observed column is 0 or 1), so
            # a chunk missing here was written where this process cannot see it
            zraw = group.create_array(
                "_raw",
                shape=(n, q + 1),
                chunks=(rows, q + 1),
                dtype="float32",
                fill_value=np.float32(np.nan),
            )
            written = self.raw.map_blocks(
                _store_rows,
                zarr_array=zraw,
                drop_axis=1,
                chunks=((1,) * self.raw.numblocks[0],),
                dtype=np.int64,
                meta=np.empty((0,), np.int64),
            )
            quer = "query" if q == 1 else "queries"
            with progress(n, f"scoring {q} {quer} on {n} items") as advance:
                advance(0)
                compute(self.client, written, progress=advance, weight=_rows_written)
            _check_written(zraw, path)
            raw = da.from_zarr(zraw, chunks=(rows, q + 1))
            post = self._post(raw)
            (floors,) = compute(self.client, self._floors(post))
            scores, masks = self._final(post, np.asarray(floors, np.float32))
            zs = group.create_array("scores", shape=(q, n), chunks=(q, rows), dtype="float32")
            zm = group.create_array("masks", shape=(q, n), chunks=(q, rows), dtype="bool")
            zo = group.create_array("observed", shape=(n,), chunks=(rows,), dtype="bool")
            store = da.store(
                [scores, masks, raw[:, q] > 0], [zs, zm, zo], lock=False, compute=False
            )
            compute(self.client, store)
            del group["_raw"]
            group.attrs.update(self._attrs([_describe(c) for c in self.classifiers], up))
        log.info("wrote %s: %d queries x %d items", path, q, n)
        return path

    def _attrs(self, classifiers: Sequence[str], up: str | None = None) -> dict[str, Any]:
        """The store's attributes: queries, threshold, query sets (with their provenance,
        ``refine`` and ``presence`` included), the classifiers (described), the map's
        source and its layout (:func:`~quash_plugins.core.layout.map_layout`): for a
        pixel map its frames, for a map with positions their up axis ``up``."""
        layout = map_layout(self.lmap, up)
        if self.lmap.positions is None:
            layout.pop("up", None)  # as a results NPZ: the up axis goes with positions
        return {
            "queries": self.queries,
            "threshold": self.threshold,
            "querysets": [qs.to_dict() for qs in self.querysets],
            "classifiers": list(classifiers),
            "map_source": {
                k: v for k, v in self.lmap.source.items() if isinstance(v, (str, int, float))
            },
            **layout,
        }

    def _write_answered(
        self, path: str | Path, overwrite: bool, group_mb: float | None, up: str | None = None
    ) -> Path:
        """The store of a config with ``refine`` or ``presence``: the queries answered in
        groups by :meth:`Quash._answer` (the code of :meth:`Quash.query_many`).

        Each group: the first pass over the map (one for the group: local, GPU or Dask
        as the Quash runs it), the map-level postprocess, the refinement pass, the
        presence check; then its rows are written, one chunk of rows at a time. Only the
        group's ``(N,)`` vectors are held (:data:`BYTES_PER_QUERY_ITEM` bytes an item
        and query, ``group_mb`` in all, at least one query) with the presence check's
        topology of the map (built once); the embeddings are read in chunks. Every group
        reads the map once per pass: ``G`` groups cost ``G`` times the passes of one
        ``query_many`` call. The client process writes the store.
        """
        from ..core.progress import progress

        zarr = require_zarr()
        path = Path(path).expanduser()
        refuse_own_input(path, self.lmap.source, folder=True)
        quash, lmap, pending = self._quash, self.lmap, self._pending
        n, q = lmap.n, len(pending)
        rows = max(1, self.raw.chunks[0][0])  # the chunk rows of the lazy path
        budget = quash.chunk_mb if group_mb is None else float(group_mb)
        size = min(q, group_size(n, int(budget * 2**20)))
        starts = list(range(0, q, size))
        passes = quash.passes
        what = f"answering {q} queries on {n} items ({', '.join(self.skipped)})"
        if len(starts) > 1:
            what += f" in {len(starts)} groups of up to {size}"
        log.info("%s: %d pass%s per group", what, passes, "es" if passes > 1 else "")
        described: list[str] = []  # the final classifiers, not kept themselves
        t0 = time.perf_counter()
        with atomic_dir(
            path, overwrite=overwrite, replaceable=is_results_zarr, kind="results store"
        ) as tmp:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            zs = group.create_array("scores", shape=(q, n), chunks=(size, rows), dtype="float32")
            zm = group.create_array("masks", shape=(q, n), chunks=(size, rows), dtype="bool")
            zo = group.create_array("observed", shape=(n,), chunks=(rows,), dtype="bool")
            with progress(n * passes * len(starts), what) as advance:
                for k, g0 in enumerate(starts):
                    # fresh copies: the answer replaces clf (refined) and adds the vectors
                    part = [replace(p, timings=dict(p.timings)) for p in pending[g0 : g0 + size]]
                    observed = quash._answer(lmap, part, advance, self._pass_client)
                    g1 = g0 + len(part)
                    for a in range(0, n, rows):
                        b = min(n, a + rows)
                        zs[g0:g1, a:b] = np.stack([p.raw[a:b] for p in part])
                        zm[g0:g1, a:b] = np.stack([p.mask[a:b] for p in part])
                        if k == 0:
                            zo[a:b] = observed[a:b]
                    described.extend(classifier_words(p) for p in part)
                    log.info(
                        "queries %d-%d of %d answered and written (%.1fs)",
                        g0 + 1,
                        g1,
                        q,
                        time.perf_counter() - t0,
                    )
                    del part, observed
            group.attrs.update(self._attrs(described, up))
        log.info("wrote %s: %d queries x %d items", path, q, n)
        return path


def query_lazy(
    quash: Any, source: Any, texts: Sequence[str] | str, client: Any = None, **read_options: Any
) -> LazyQuery:
    """Fit one classifier per query and build the lazy one-pass graph over the map.

    Nothing touches the embeddings until the result is computed or written. The text
    side is :meth:`Quash.query_many`'s own (each query expanded once, one encoder call,
    one classifier fitted per query).

    A config's ``refine`` and ``presence`` steps need each query's whole first-pass
    mask, then its whole final mask (connected components), so they cannot be blocks of
    a dask graph. The returned :class:`LazyQuery` therefore keeps two faces:

    - :meth:`LazyQuery.to_zarr` (and :func:`query_to_zarr`, ``--out *.zarr``) applies
      them: it answers the queries in groups with the code of ``query_many`` and writes
      the same masks and scores, holding ``(N,)`` vectors per query of a group, never the
      embeddings;
    - :attr:`LazyQuery.scores`, :attr:`LazyQuery.masks` and :meth:`LazyQuery.compute`
      are the first pass only and warn so when the config has either step
      (:attr:`LazyQuery.skipped`): an absent object may match there. Without the steps
      they are the whole answer.

    Why not dask arrays read back from a written store: that would write a store the
    caller did not ask for, somewhere. The graph stays honest about what it is, and the
    writer, which owns a store, gives the full answer.

    ``client`` runs the graph (default: the Quash's client, else the process's default
    client, else threads); given here, it also runs the passes of ``to_zarr``, which
    otherwise run as ``query_many`` runs them.

    Examples
    --------
    >>> lazy = query_lazy(quash, "map.zarr", ["chair", "sofa"], client)  # doctest: +SKIP
    >>> lazy.masks            # (2, N) bool dask array          # doctest: +SKIP
    >>> lazy.to_zarr("result.zarr")                              # doctest: +SKIP
    """
    if isinstance(texts, str):
        texts = [texts]
    texts = [check_query(t) for t in texts]
    pass_client = client
    client = current_client(client if client is not None else getattr(quash, "client", None))
    t0 = time.perf_counter()
    lmap = quash.read_map(source, **read_options)
    t_read = time.perf_counter() - t0
    quash.check_dimension(lmap)
    from .map_fit import warn_if_empty

    warn_if_empty(lmap)
    # query_many's text side: expand once, one encoder call, one classifier per query
    pending = quash._prepare(lmap, texts, t_read) if texts else []
    querysets = [p.queryset for p in pending]
    classifiers = [p.clf for p in pending]
    chunk_bytes = int(getattr(quash, "chunk_mb", 256.0) * 2**20)
    held = ship(BlockScorer(classifiers, chunk_bytes))
    raw = scores_graph(lmap, classifiers, chunk_bytes, client, held=held)
    return LazyQuery(
        querysets,
        classifiers,
        raw,
        quash.threshold,
        client,
        held,
        lmap,
        quash=quash,
        pending=pending,
        pass_client=pass_client,
    )


def query_to_zarr(
    quash: Any,
    source: Any,
    texts: Sequence[str] | str,
    out_path: str | Path,
    client: Any = None,
    group_mb: float | None = None,
    up: str | None = None,
    **read_options: Any,
) -> Path:
    """Answer ``texts`` on ``source`` and write the results to the zarr store ``out_path``.

    The store holds ``scores (Q, N) float32``, ``masks (Q, N) bool``, ``observed (N,) bool``
    and the queries, query sets (with their ``refine`` and ``presence`` provenance) and
    classifiers as attributes; masks and scores are those of :meth:`Quash.query_many`,
    the config's ``refine`` and ``presence`` steps included (see
    :meth:`LazyQuery.to_zarr`; ``group_mb`` bounds the vectors held for them). Without
    those steps, and a distributed client, the workers write the chunks, so ``out_path``
    must be on storage they share. ``up``: the up axis of the map's positions, recorded
    in the store (else the map's own; see :meth:`LazyQuery.to_zarr`).
    """
    lazy = query_lazy(quash, source, texts, client, **read_options)
    return lazy.to_zarr(out_path, group_mb=group_mb, up=up)
