"""Lazy query results: masks and scores as dask arrays, written to zarr chunk by chunk.

Map-level postprocessing (``Classifier.postprocess_scores``) needs the whole score
vector. Here it is done with dask reductions: a classifier whose postprocess depends only
on the minimum and maximum of the observed scores (identity, min-max normalisation,
clipping) is applied block by block with those two values; any other postprocess is
detected by a probe and falls back to one ``(N,)`` float32 vector per such query.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.base import clone

from ..core.atomic import atomic_dir, refuse_own_input
from ..core.types import QuerySet, check_query
from .classify import BlockScorer
from .dask_client import current_client, require_dask, require_zarr
from .dask_executor import compute, scores_graph, ship

log = logging.getLogger(__name__)


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


class LazyQuery:
    """The lazy answer to several queries over one map (see :func:`query_lazy`).

    Attributes
    ----------
    raw
        ``(N, Q + 1)`` float32 dask array: raw decision values, last column observed.
    """

    def __init__(self, querysets, classifiers, raw, threshold, client, held, lmap) -> None:
        self.querysets: list[QuerySet] = querysets
        self.classifiers = classifiers
        self.raw = raw
        self.threshold = float(threshold)
        self.client = client
        self.lmap = lmap
        self._held = held
        self.kinds = [postprocess_kind(c) for c in classifiers]

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
        post = self._post(self.raw)
        return self._final(post, self._floors(post))

    @property
    def scores(self) -> Any:
        """``(Q, N)`` float32 dask array, as :attr:`QueryResult.scores` (postprocessed)."""
        return self._lazy()[0]

    @property
    def masks(self) -> Any:
        """``(Q, N)`` bool dask array, as :attr:`QueryResult.mask`."""
        return self._lazy()[1]

    def compute(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(scores (Q, N) float32, masks (Q, N) bool, observed (N,) bool)`` in memory."""
        scores, masks = self._lazy()
        return tuple(np.asarray(x) for x in compute(self.client, scores, masks, self.observed))

    def to_zarr(self, path: str | Path, overwrite: bool = True) -> Path:
        """Write ``scores``, ``masks`` and ``observed`` to a zarr store, atomically.

        Three passes, each bounded by the chunk size: the map pass writes raw scores
        (``4 (Q + 1)`` bytes per row) into the store; the two small passes over them
        compute the map-level statistics and write the final arrays.
        """
        zarr = require_zarr()
        da = require_dask()
        path = Path(path).expanduser()
        refuse_own_input(path, self.lmap.source, folder=True)
        n, q = self.raw.shape[0], len(self.classifiers)
        rows = max(1, self.raw.chunks[0][0])  # an empty map has one chunk of 0 rows
        with atomic_dir(path, overwrite=overwrite) as tmp:
            group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
            zraw = group.create_array(
                "_raw", shape=(n, q + 1), chunks=(rows, q + 1), dtype="float32"
            )
            (_,) = compute(self.client, da.store(self.raw, zraw, lock=False, compute=False))
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
            group.attrs.update(
                {
                    "queries": self.queries,
                    "threshold": self.threshold,
                    "querysets": [qs.to_dict() for qs in self.querysets],
                    "classifiers": [_describe(c) for c in self.classifiers],
                    "map_source": {
                        k: v
                        for k, v in self.lmap.source.items()
                        if isinstance(v, (str, int, float))
                    },
                }
            )
        log.info("wrote %s: %d queries x %d items", path, q, n)
        return path


def _describe(clf: Any) -> str:
    describe = getattr(clf, "describe", None)
    return describe() if callable(describe) else type(clf).__name__


def query_lazy(
    quash: Any, source: Any, texts: Sequence[str] | str, client: Any = None, **read_options: Any
) -> LazyQuery:
    """Fit one classifier per query and build the lazy one-pass graph over the map.

    Nothing touches the embeddings until the result is computed or written. The lazy
    graph is the first pass only: a config's ``refine`` and ``presence`` steps need the
    whole mask in memory and are not applied (a warning says so), so an absent object is
    not reported empty here; use :meth:`Quash.query_many` for them.

    Examples
    --------
    >>> lazy = query_lazy(quash, "map.zarr", ["chair", "sofa"], client)  # doctest: +SKIP
    >>> lazy.masks            # (2, N) bool dask array          # doctest: +SKIP
    >>> lazy.to_zarr("result.zarr")                              # doctest: +SKIP
    """
    if isinstance(texts, str):
        texts = [texts]
    texts = [check_query(t) for t in texts]
    skipped = [k for k in ("refine", "presence") if getattr(quash, k, None) is not None]
    if skipped:
        import warnings

        warnings.warn(
            f"Lazy results (--out *.zarr) are the first pass only: the config's "
            f"{' and '.join(skipped)} step{'s are' if len(skipped) > 1 else ' is'} not "
            "applied, so absent objects may match. Write .npz (in memory) to apply them.",
            stacklevel=2,
        )
    client = current_client(client if client is not None else getattr(quash, "client", None))
    lmap = quash.read_map(source, **read_options)
    quash.check_dimension(lmap)
    from .pipeline import warn_if_empty

    warn_if_empty(lmap)
    querysets = [quash.expand(text, lmap) for text in texts]
    # one encoder call for the strings of every query set
    sets = quash.training_sets(querysets)
    classifiers = [clone(quash.classifier).fit(X, y) for X, y, _ in sets]
    chunk_bytes = int(getattr(quash, "chunk_mb", 256.0) * 2**20)
    held = ship(BlockScorer(classifiers, chunk_bytes))
    raw = scores_graph(lmap, classifiers, chunk_bytes, client, held=held)
    return LazyQuery(querysets, classifiers, raw, quash.threshold, client, held, lmap)


def query_to_zarr(
    quash: Any,
    source: Any,
    texts: Sequence[str] | str,
    out_path: str | Path,
    client: Any = None,
    **read_options: Any,
) -> Path:
    """Answer ``texts`` on ``source`` and write the results to the zarr store ``out_path``.

    The store holds ``scores (Q, N) float32``, ``masks (Q, N) bool``, ``observed (N,) bool``
    and the queries, query sets and classifiers as attributes. With a distributed client
    the workers write the chunks, so ``out_path`` must be on storage they share.
    """
    return query_lazy(quash, source, texts, client, **read_options).to_zarr(out_path)
