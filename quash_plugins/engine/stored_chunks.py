"""How a chunked store's own chunks meet the pass's row chunks (``chunk_mb``).

A zarr array or a chunked HDF5 dataset is decoded a whole stored chunk at a time. The
classification pass reads the map in chunks of ``LatentMap.chunk_rows(chunk_bytes)``
rows (the same rows on every backend, which keeps results bit-identical across them), so
a stored chunk that straddles two of them is decoded twice, and one larger than a pass
chunk is decoded once for every pass chunk it covers, each time whole. Stores written by
``quash convert`` (16 MiB row chunks) cost a few per cent at the default ``chunk_mb``; a
store written by another tool with large or column-split chunks can cost many times the
reads and more memory than ``chunk_mb``: :func:`warn_stored_chunks` says so once per
map, with the fix. The pass chunks are not changed to fit the store, so the results stay
those of the same map in any other format.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core.once import first_time
from ..core.types import LatentMap

log = logging.getLogger(__name__)

#: Average decodes per stored chunk above which :func:`warn_stored_chunks` warns.
DECODE_LIMIT = 1.5

#: MiB of one stored chunk of a store written by ``quash convert``
#: (:func:`quash_plugins.adapters._zarr_store.store_chunk_rows`).
CONVERT_CHUNK_MB = 16.0


def stored_row_chunks(embeddings: Any) -> tuple[int, int] | None:
    """``(rows, columns)`` of one stored chunk of a zarr array or chunked HDF5 dataset,
    else None (numpy, memmap, dask, a contiguous HDF5 dataset)."""
    chunks = getattr(embeddings, "chunks", None)
    if not isinstance(chunks, tuple) or len(chunks) != 2:
        return None
    if not all(isinstance(c, (int, np.integer)) for c in chunks):
        return None  # a dask array's chunks are tuples of tuples
    return int(chunks[0]), int(chunks[1])


def decodes_per_chunk(n: int, rows: int, stored: int) -> float:
    """Average times each stored chunk of ``stored`` rows is decoded when ``n`` rows are
    read in consecutive reads of ``rows`` rows.

    >>> decodes_per_chunk(100, 50, 50), decodes_per_chunk(100, 10, 50)
    (1.0, 5.0)
    """
    if n <= 0:
        return 1.0
    starts = np.arange(0, n, max(1, rows), dtype=np.int64)
    stops = np.minimum(starts + rows, n)
    decodes = int(((stops - 1) // stored - starts // stored + 1).sum())
    return decodes / -(-n // stored)


def warn_stored_chunks(lmap: LatentMap, rows: int, chunk_bytes: int) -> None:
    """Warn once per map when its stored chunks are read inefficiently in chunks of
    ``rows`` rows (see the module's docstring)."""
    shape = stored_row_chunks(lmap.embeddings)
    if shape is None or lmap.n == 0:
        return
    stored, cols = shape
    if stored >= lmap.n and rows >= lmap.n:
        return
    amp = decodes_per_chunk(lmap.n, rows, stored)
    if amp <= DECODE_LIMIT:
        return
    where = lmap.source.get("path", "the map")
    if not first_time(("stored-chunks", str(where))):
        return
    item = lmap.dtype.itemsize
    size = stored * lmap.dim * item
    split = f" x {cols} columns" if cols < lmap.dim else ""
    over = (
        f"; a read decodes {size / 2**20:.0f} MiB, more than chunk_mb" if size > chunk_bytes else ""
    )
    fix = f"raise chunk_mb to {4 * stored * lmap.dim * 4 / 2**20:.0f} or more (4 stored chunks a read)"
    if cols < lmap.dim or size > CONVERT_CHUNK_MB * 2**20:
        fix = f"rewrite the store in row chunks with `quash convert {where} NEW.zarr`, or {fix}"
    log.warning(
        "%s: its embeddings are stored in chunks of %d rows%s (%.1f MiB a row of chunks) and read in chunks "
        "of %d rows (chunk_mb): each stored chunk is decoded %.1f times on average%s. To "
        "read each once, %s.",
        where,
        stored,
        split,
        size / 2**20,
        rows,
        amp,
        over,
        fix,
    )


#: Rows per pass chunk under which :func:`warn_small_chunks` warns (when there are many).
SMALL_ROWS = 256
#: ... and only when the pass then has more chunks than this.
SMALL_MANY = 64


def warn_small_chunks(lmap: LatentMap, rows: int, chunk_bytes: int) -> None:
    """Warn once per chunk size when ``chunk_mb`` cuts the map into many chunks of fewer
    than :data:`SMALL_ROWS` rows: every chunk pays a fixed cost (a task, a read, a
    BLAS call), so a ``chunk_mb`` such as ``1e-6`` runs for hours on a map that the
    default answers in seconds."""
    n = lmap.n
    if rows >= SMALL_ROWS or rows >= n or -(-n // max(1, rows)) <= SMALL_MANY:
        return
    if not first_time(("small-chunks", int(rows), int(chunk_bytes))):
        return
    log.warning(
        "chunk_mb gives chunks of %s bytes, only %d rows of this map (%d rows x %d): the "
        "pass runs %d chunks of %d rows, each with a fixed cost, far slower than chunks of "
        "thousands; raise chunk_mb (a chunk's memory is about chunk_mb MiB; the default "
        "is 256).",
        f"{int(chunk_bytes):,}",
        rows,
        n,
        lmap.dim,
        -(-n // rows),
        rows,
    )
