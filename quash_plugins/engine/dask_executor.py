"""Classification as one ``map_blocks`` pass over row chunks, on any Dask scheduler."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.maps import map_read_error
from ..core.types import LatentMap
from .classify import BlockScorer, extra_bytes_per_row
from .dask_arrays import as_dask, forget_scattered
from .dask_client import current_client, require_dask
from .stored_chunks import warn_small_chunks, warn_stored_chunks

log = logging.getLogger(__name__)


class ClusterError(QuashError):
    """The Dask cluster failed (workers lost, scheduler gone); no partial result is kept."""


def score_block(
    block: np.ndarray,
    scorer: BlockScorer,
    normalize: bool,
    source: dict[str, Any],
    block_info: Any = None,
) -> np.ndarray:
    """Scores of one row chunk: ``(rows, Q + 1)`` float32, the last column ``observed``.

    The same fused pass as the in-memory path (:meth:`BlockScorer.run`) on the same
    blocks: the chunk is read as stored (float16 is converted block by block), checked
    for NaN/Inf from its norms, every stacked query and cosine rule shares one GEMM per
    block, and the rows are never normalised in place. One thread per task (Dask runs
    the tasks in parallel), with a single-threaded BLAS.
    """
    start = int(block_info[0]["array-location"][0][0]) if block_info else 0
    return scorer.score(block, start, normalize, source, threads=1)


def ship(scorer: BlockScorer) -> Any:
    """Hold ``scorer`` once in the graph: one task every chunk task depends on.

    Each worker receives it once (from the client or a peer) and keeps it while the pass
    runs. Unlike ``Client.scatter`` data, a graph task can be recomputed when the worker
    holding it dies, so a killed worker never loses the classifiers.
    """
    import dask

    return dask.delayed(scorer, pure=False)


def scores_graph(
    lmap: LatentMap,
    classifiers: Sequence[Any],
    chunk_bytes: int,
    client: Any = None,
    held: Any = None,
) -> Any:
    """The lazy ``(N, Q + 1)`` float32 dask array of raw scores plus the observed column.

    Chunks hold ``lmap.chunk_rows(chunk_bytes, ...)`` rows, the same rows as the in-memory
    path, so a worker's working set is bounded by ``chunk_bytes`` whatever N is. ``held`` is
    an already shipped :class:`~quash_plugins.engine.classify.BlockScorer` (from
    :func:`ship`), if any.
    """
    require_dask()
    rows = lmap.chunk_rows(int(chunk_bytes), extra_bytes_per_row(classifiers))
    warn_small_chunks(lmap, rows, int(chunk_bytes))
    warn_stored_chunks(lmap, rows, int(chunk_bytes))
    try:  # an in-memory map is scattered to the workers here
        emb = as_dask(lmap, rows, client)
    except OSError as exc:
        if exc.filename is not None:  # a file of the map, not the cluster
            raise
        raise _cluster_error(exc) from exc
    except _cluster_errors() as exc:
        raise _cluster_error(exc) from exc
    if held is None:
        held = ship(BlockScorer(classifiers, chunk_bytes))
    return emb.map_blocks(
        score_block,
        held,
        bool(lmap.normalize),
        dict(lmap.source),
        chunks=(emb.chunks[0], (len(classifiers) + 1,)),
        dtype=np.float32,
        meta=np.empty((0, 0), np.float32),
        token="quash-scores",
    )


def _cluster_errors() -> tuple[type[BaseException], ...]:
    import importlib

    errors: list[type[BaseException]] = [OSError, TimeoutError]
    for module, name in (
        ("distributed.scheduler", "KilledWorker"),
        ("distributed.comm.core", "CommClosedError"),
        ("distributed.client", "FutureCancelledError"),
        ("asyncio", "CancelledError"),
        ("concurrent.futures", "CancelledError"),
    ):
        try:
            errors.append(getattr(importlib.import_module(module), name))
        except (ImportError, AttributeError):  # pragma: no cover - older distributed
            continue
    return tuple(errors)


def compute(client: Any, *arrays: Any, progress: Any = None, weight: Any = None) -> tuple[Any, ...]:
    """Compute dask collections on ``client`` (or threads), turning cluster faults into
    :class:`ClusterError`.

    ``progress(rows)`` (one array given, row-chunked) is called as each row block of it
    finishes, from this thread: on threads through a dask callback, on a client as the
    block's future completes. ``weight(block)`` is what a finished block adds (default:
    its rows), for an array whose blocks stand for more rows than they hold.
    """
    import dask

    try:
        if progress is not None and len(arrays) == 1:
            return (_compute_counted(client, arrays[0], progress, weight),)
        if client is not None:
            return tuple(client.compute(list(arrays), sync=True))
        return dask.compute(*arrays, scheduler="threads")
    except QuashError:
        raise
    except OSError as exc:
        if exc.filename is not None:  # a file that cannot be read, not a cluster fault
            raise
        raise _cluster_error(exc) from exc
    except _cluster_errors() as exc:
        raise _cluster_error(exc) from exc
    except RuntimeError as exc:
        if "deserialization of the task graph" not in str(exc):
            raise
        raise ClusterError(
            "The Dask scheduler could not read the query's tasks: it runs other versions "
            "of quash-plugins or of its dependencies (numpy, scikit-learn, dask) than "
            "this process, or was started before they changed. Restart the scheduler "
            "and the workers from this environment (see docs/scale.md)."
        ) from exc


def _compute_counted(client: Any, array: Any, progress: Any, weight: Any = None) -> np.ndarray:
    """``array`` computed with ``progress(rows)`` after each finished row block
    (``weight(block)`` instead of its rows when given)."""
    import dask

    if client is None:
        from dask.callbacks import Callback

        name = array.name
        rows = dict(enumerate(array.chunks[0]))

        def done(key, result, dsk, state, worker_id) -> None:
            if isinstance(key, tuple) and key and key[0] == name:
                progress(weight(result) if weight else rows.get(key[1], 0))

        with Callback(posttask=done):
            (out,) = dask.compute(array, scheduler="threads")
        return out
    from distributed import as_completed

    blocks = array.to_delayed().ravel().tolist()
    futures = client.compute(blocks)
    index = {f.key: i for i, f in enumerate(futures)}
    parts: list[Any] = [None] * len(futures)
    for fut in as_completed(futures):
        part = fut.result()  # raises the block's error here
        parts[index[fut.key]] = part
        progress(weight(part) if weight else len(part))
    return np.concatenate(parts) if parts else np.empty(array.shape, array.dtype)


def _address(client: Any) -> str:
    """The scheduler's address of ``client`` (``tls://127.0.0.1:40123``), not the repr of
    its connection pool (``<pooled rpc to ...>``)."""
    scheduler = getattr(client, "scheduler", None)
    return str(getattr(scheduler, "address", None) or scheduler or client)


def _cluster_error(exc: BaseException) -> ClusterError:
    return ClusterError(
        f"The Dask cluster failed during the query ({type(exc).__name__}: {exc}). No "
        "result was written. Check that the workers have enough memory for the chunk "
        "size (lower chunk_mb), then run the query again (a map held in memory, whose "
        "chunks were scattered to the workers and lost with a worker that died, is "
        "then sent to them again)."
    )


def classify_dask(
    lmap: LatentMap,
    classifiers: Sequence[Any],
    chunk_bytes: int = 256 * 2**20,
    client: Any = None,
    progress: Any = None,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Run every fitted classifier over ``lmap`` in one ``map_blocks`` pass on Dask.

    Parameters
    ----------
    lmap
        The map; its embeddings may be numpy, memmap, h5py, zarr or dask.
    classifiers
        Fitted classifiers; they travel to the workers once.
    chunk_bytes
        Float32 working-set budget of one chunk task.
    client
        A ``dask.distributed.Client``; default the current client, else local threads.
    progress
        ``progress(rows)``, called as each chunk's scores come back (the rows of the map
        done so far add up to ``lmap.n``).

    Returns
    -------
    scores
        One ``(N,)`` float32 raw score vector per classifier (before postprocessing).
    observed
        ``(N,)`` bool, False for zero rows (they never match).

    Examples
    --------
    >>> import numpy as np
    >>> from quash_plugins import registry
    >>> clf = registry.create("classifiers", "contrast").fit(
    ...     np.eye(2, dtype=np.float32), np.array([1, 0]))
    >>> m = LatentMap(np.array([[1, 0], [0, 1], [0, 0]], dtype=np.float32))
    >>> scores, observed = classify_dask(m, [clf])
    >>> scores[0].tolist(), observed.tolist()
    ([1.0, -1.0, 0.0], [True, True, False])
    """
    if not classifiers:
        raise QuashError("classify_dask needs at least one fitted classifier.")
    client = current_client(client)
    graph = scores_graph(lmap, classifiers, chunk_bytes, client)
    log.info(
        "dask pass: %d chunks of %d rows, %d queries, %s",
        graph.numblocks[0],
        graph.chunks[0][0],
        len(classifiers),
        f"the scheduler at {_address(client)}" if client is not None else "local threads",
    )
    try:
        (out,) = compute(client, graph, progress=progress)
    except ClusterError:
        # a map scattered to the workers may have lost chunks with a worker that died
        # (scattered data is not recomputed): the next pass scatters it again
        forget_scattered(lmap.embeddings, client)
        raise
    except QuashError:
        raise
    except Exception as exc:  # noqa: BLE001 - a chunk that cannot be read is the map's fault
        raise map_read_error(
            lmap.source.get("path", "the map"), exc, lmap.source.get("adapter"), "the embeddings"
        ) from exc
    out = np.asarray(out)
    q = len(classifiers)
    if out.shape != (lmap.n, q + 1) or np.isnan(out).any():
        raise ClusterError(
            f"The Dask pass returned an incomplete result (shape {out.shape}, expected "
            f"{(lmap.n, q + 1)}); refusing to return a partial mask. Run the query again."
        )
    observed = out[:, q] > 0
    return [np.ascontiguousarray(out[:, i]) for i in range(q)], observed
