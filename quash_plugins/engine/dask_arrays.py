"""Any map's embeddings as a row-chunked dask array, read lazily on the workers.

Which reader a chunk task gets depends on what :attr:`LatentMap.embeddings` is:

- dask array: rechunked along rows only;
- zarr array: a :class:`ZarrRows` around it (it pickles with its store's URL, as
  ``da.from_zarr``'s does); a chunk that fails to read is reported by its rows and its
  zarr chunk key, as the in-memory path reports it;
- an HDF5 dataset (the VLMaps and ConceptFusion adapters' :class:`H5Rows`, or a
  caller's own ``h5py`` dataset, which does not pickle and becomes one): a small
  picklable reader holding only the file name and the dataset path. It opens the file
  read-only on the worker for every chunk, so the file must be reachable at the same
  path from every worker (a shared file system);
- numpy memmap: an :class:`MemmapRows` reopening the file by name on the worker (a
  tensor of a ``torch.save`` file, which stores it uncompressed, is one too: OpenScene's
  ``feat``);
- an adapter's lazy row array (``IndexedRows``, ``MaskedRows``: OpenLex3D, OpenScene,
  ConceptGraphs; ``ConcatRows``: per-image features): held once in the graph, and
  pickled without its data: memory-mapped tables and indices as (file, offset, shape,
  dtype), frames as their files, each reopened on the worker. The graph does not grow
  with the table. Only arrays that live in memory with no file behind them (a
  ConceptGraphs table, a legacy ``.pt`` OpenScene file) travel with their values;
- numpy array in memory (an NPZ map, an array built in Python), given a distributed
  client: its row chunks are scattered to the workers (``Client.scatter``), each chunk
  to one worker, once per map and client (not once per pass: the array of their
  futures is kept while the map's embeddings array lives, and every later pass, a
  refinement pass, another ``query_many`` call or ``LazyQuery.to_zarr``, reuses it,
  rechunked on the workers if its pass wants other chunk rows). The graph holds only
  the futures: a few kB whatever the size of the map, where the rows inside the graph
  made Dask warn "Sending large graph" (and the scheduler hold the whole map) from
  about 10 MB on. Not broadcast: every worker would hold the whole map. A chunk lost
  with a worker that died, or a client that was closed, is not reused: the next pass
  scatters the map again. Without a client (local threads), or for anything else with
  ``shape``/``dtype``/slicing, chunks are sliced on the client and travel inside the
  graph.
"""

from __future__ import annotations

import os
import threading
import weakref
from typing import Any

import numpy as np

from ..core.h5rows import H5Rows
from ..core.maps import memmap_ref
from ..core.types import LatentMap, prepare_block
from .dask_client import require_dask


class MemmapRows:
    """Picklable view of a C-ordered array stored raw in a file at ``offset`` bytes."""

    def __init__(self, filename: str, offset: int, shape: tuple[int, ...], dtype: Any) -> None:
        self.filename = str(filename)
        self.offset = int(offset)
        self.shape = tuple(int(s) for s in shape)
        self.dtype = np.dtype(dtype)
        self.ndim = len(self.shape)

    def __getitem__(self, key: Any) -> np.ndarray:
        mm = np.memmap(self.filename, self.dtype, "r", offset=self.offset, shape=self.shape)
        return np.array(mm[key])


class ZarrRows:
    """Picklable rows of a zarr array whose read failures name the rows and the chunk.

    ``where`` and ``adapter`` are the map's path and adapter, for the message.
    """

    def __init__(self, array: Any, where: str, adapter: str | None) -> None:
        self.array = array
        self.where = str(where)
        self.adapter = adapter
        self.shape = tuple(int(s) for s in array.shape)
        self.dtype = np.dtype(array.dtype)
        self.ndim = len(self.shape)

    def __getitem__(self, key: Any) -> np.ndarray:
        self._check_store()
        try:
            return np.asarray(self.array[key])
        except Exception as exc:  # noqa: BLE001 - any failure to read rows is the map's
            from ..core.errors import QuashError
            from ..core.maps import map_read_error
            from .classify import _chunk_keys

            if isinstance(exc, QuashError):
                raise
            rows = key[0] if isinstance(key, tuple) else key
            start, stop, _ = rows.indices(self.shape[0]) if isinstance(rows, slice) else (0, 0, 1)
            what = f"rows {start}-{stop - 1} of the embeddings" if stop > start else ""
            what += _chunk_keys(self.array, start, stop) if stop > start else ""
            raise map_read_error(self.where, exc, self.adapter, what) from exc

    def _check_store(self) -> None:
        """A local store that is not there (on a worker that does not share the map's
        file system) is an error: zarr would read its chunks as zeros, unobserved rows
        that never match."""
        root = getattr(getattr(self.array, "store", None), "root", None)
        if root is None or os.path.isdir(root):
            return
        import socket

        from ..core.errors import MapFormatError

        raise MapFormatError(
            f"{self.where}: its zarr store {root} is not there on {socket.gethostname()}, "
            "where a Dask worker reads its chunks. Every worker reads the map itself: put "
            "it at the same path on every worker (a shared file system), or leave out "
            "--scheduler to run a local cluster (see docs/scale.md)."
        )


def _reader(emb: Any) -> tuple[Any, str | None]:
    """A picklable stand-in for ``emb`` plus a stable name token (None when there is none)."""
    mod = type(emb).__module__ or ""
    if mod.startswith("h5py"):  # a caller's own open dataset
        emb = H5Rows.from_dataset(emb)
    if isinstance(emb, H5Rows):  # it pickles as its file name and dataset path
        return emb, f"{emb.filename}:{emb.dataset}:{emb.stamp}"
    ref = memmap_ref(emb)
    if ref is not None:
        filename, offset, shape, dtype = ref
        stamp = os.stat(filename).st_mtime_ns
        return MemmapRows(filename, offset, shape, dtype), f"{filename}:{offset}:{stamp}"
    return emb, None


#: The scattered arrays of in-memory maps: ``id(embeddings)`` -> (a weak reference to
#: the embeddings array, {client id: (client, dask array, the chunks' futures)}).
#: numpy arrays are weak-referenceable but not hashable, hence the id with its weak
#: reference, whose callback drops the entry when the array dies (its futures then
#: release the chunks on the workers).
_SCATTERED: dict[int, tuple[weakref.ref, dict[str, tuple[Any, Any, tuple]]]] = {}
_SCATTERED_LOCK = threading.Lock()


def _forget(key: int) -> Any:
    def drop(_ref: Any) -> None:
        with _SCATTERED_LOCK:
            entry = _SCATTERED.get(key)
            if entry is not None and entry[0] is _ref:
                del _SCATTERED[key]

    return drop


def _usable(client: Any, futures: tuple) -> bool:
    """Whether chunks scattered to ``client`` can serve a pass: the client is still
    running and every chunk is still held by a worker (a worker that died loses its
    chunks: their futures turn ``lost`` or ``cancelled``)."""
    if getattr(client, "status", None) != "running":
        return False
    return all(f.status == "finished" for f in futures)


def scattered_array(emb: np.ndarray, client: Any) -> Any:
    """The cached scattered array of ``emb`` on ``client``, or None (nothing usable)."""
    with _SCATTERED_LOCK:
        entry = _SCATTERED.get(id(emb))
        if entry is None or entry[0]() is not emb:
            return None
        held = entry[1].get(str(client.id))
    if held is None or held[0] is not client or not _usable(client, held[2]):
        return None
    return held[1]


def forget_scattered(emb: Any, client: Any = None) -> None:
    """Drop the scattered chunks of ``emb`` (on ``client``, default every client): the
    next pass scatters the map again. Their futures are released when unreferenced."""
    with _SCATTERED_LOCK:
        entry = _SCATTERED.get(id(emb))
        if entry is None or entry[0]() is not emb:
            return
        if client is None:
            entry[1].clear()
        else:
            entry[1].pop(str(client.id), None)


def _scattered(emb: np.ndarray, rows: int, client: Any) -> Any:
    """``emb`` as a dask array of ``rows``-row chunks scattered to ``client``'s workers.

    Each chunk is sent once, to one worker (spread over them), and once per map and
    client: the array is kept (see :data:`_SCATTERED`) and reused by every later pass
    while ``emb`` lives, rechunked on the workers when ``rows`` differs. The graph holds
    only the futures, which keep the chunks on the workers as long as the array lives.
    """
    da = require_dask()
    chunks = (rows, emb.shape[1])
    x = scattered_array(emb, client)
    if x is not None:  # rechunk returns x itself when its chunks are these
        return x.rechunk(chunks)
    parts = [emb[start : start + rows] for start in range(0, emb.shape[0], rows)]
    # hash=False: fresh keys, without hashing every byte of the map, and no key shared
    # with the chunks of a map scattered before while the scheduler releases them
    futures = client.scatter(parts, hash=False)
    meta = np.empty((0,) * emb.ndim, emb.dtype)
    blocks = [
        da.from_delayed(f, shape=p.shape, dtype=p.dtype, meta=meta)
        for f, p in zip(futures, parts, strict=True)
    ]
    del parts  # views of emb: the cached array must not keep the map alive
    x = da.concatenate(blocks, axis=0) if len(blocks) > 1 else blocks[0]
    key = id(emb)
    with _SCATTERED_LOCK:
        entry = _SCATTERED.get(key)
        if entry is None or entry[0]() is not emb:
            entry = (weakref.ref(emb, _forget(key)), {})
            _SCATTERED[key] = entry
        held = entry[1]
        for cid in [c for c, h in held.items() if getattr(h[0], "status", None) != "running"]:
            del held[cid]  # the arrays of closed clients
        held[str(client.id)] = (client, x, tuple(futures))
    return x


def as_dask(lmap: LatentMap, chunk_rows: int, client: Any = None) -> Any:
    """``lmap.embeddings`` as an ``(N, D)`` dask array in chunks of ``chunk_rows`` rows.

    The values are the stored ones (not yet cast, checked or normalised; see
    :func:`prepared_blocks`). Nothing is read until the array is computed. With a
    distributed ``client``, a numpy array in memory is scattered to its workers now,
    chunk by chunk, rather than carried in the graph.

    Examples
    --------
    >>> import numpy as np
    >>> m = LatentMap(np.ones((10, 4), dtype=np.float16))
    >>> as_dask(m, 4).chunks
    ((4, 4, 2), (4,))
    """
    da = require_dask()
    emb = lmap.embeddings
    rows = max(1, min(int(chunk_rows), lmap.n))
    chunks = (rows, lmap.dim)
    if isinstance(emb, da.Array):
        return emb.rechunk(chunks)
    if type(emb).__module__.startswith("zarr"):
        from dask.base import tokenize

        where = lmap.source.get("path", "the map")
        reader = ZarrRows(emb, where, lmap.source.get("adapter"))
        token = tokenize(str(emb.store), str(emb.path), emb.shape, str(emb.dtype), chunks)
        name = f"quash-zarr-embeddings-{token}"
        return da.from_array(reader, chunks=chunks, name=name, lock=False, asarray=True)
    reader, token = _reader(emb)
    if token is not None:
        from dask.base import tokenize

        name = f"quash-embeddings-{tokenize(token, chunks)}"
        return da.from_array(reader, chunks=chunks, name=name, lock=False, asarray=True)
    if client is not None and isinstance(emb, np.ndarray) and emb.ndim == 2 and len(emb):
        return _scattered(emb, rows, client)
    return da.from_array(emb, chunks=chunks, asarray=True)


def _prepare(block: np.ndarray, normalize: bool, source: dict, block_info: Any = None):
    start = 0
    if block_info and 0 in block_info:
        start = int(block_info[0]["array-location"][0][0])
    return prepare_block(np.array(block, dtype=np.float32), start, normalize, source, owned=True)


def prepared_blocks(lmap: LatentMap, chunk_rows: int, client: Any = None) -> Any:
    """:func:`as_dask` cast to float32, checked for NaN/Inf and L2-normalised if asked.

    A bad row raises :class:`MapFormatError` naming its global row index.
    """
    x = as_dask(lmap, chunk_rows, client)
    return x.map_blocks(
        _prepare,
        bool(lmap.normalize),
        dict(lmap.source),
        dtype=np.float32,
        meta=np.empty((0, 0), np.float32),
    )
