"""quash-plugins' zarr map store: embeddings chunked by rows, written atomically.

Layout of ``MAP.zarr`` (a zarr group, format 3):

- ``embeddings`` ``(N, D)``, dtype kept (float16 stays float16), chunks of whole rows;
- ``positions`` ``(N, 3)`` float32, ``colors`` ``(N, 3)`` uint8, ``labels`` ``(N,)`` int64,
  ``grid_index`` ``(N, 3)`` int64 when the map has them;
- group attributes ``quash_map`` (format version), ``chunks_complete`` (every chunk is
  stored, even an all-zero one), ``kind``, ``voxel_size``, ``normalize``,
  ``label_names``, ``frames`` and ``source``.

Zarr reads a chunk missing from the store as the fill value (zeros), so a damaged store
would silently read as unobserved rows. :func:`check_chunks` compares the chunks stored
with the array's chunk grid when the map is opened: a store written here
(``chunks_complete``) with a missing chunk is an error naming the chunk and its rows;
any other store gets a warning with the share of rows that will read as zeros.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_dir, refuse_own_input
from ..core.errors import MapFormatError
from ..core.optional import require
from ..core.progress import progress
from ..core.types import SOURCE_INPUTS, FrameInfo, LatentMap, record_inputs
from ._npz import result_hint

log = logging.getLogger(__name__)

FORMAT_VERSION = 1
ROW_ARRAYS = ("positions", "colors", "labels", "grid_index")


def store_chunk_rows(dim: int, itemsize: int, chunk_mb: float = 16.0) -> int:
    """Rows per stored chunk so that one chunk holds about ``chunk_mb`` MiB."""
    return max(1, int(chunk_mb * 2**20 // max(1, dim * itemsize)))


def write_zarr_map(
    lmap: LatentMap, path: str | Path, *, chunk_mb: float = 16.0, overwrite: bool = True
) -> Path:
    """Write ``lmap`` as a zarr store at ``path``, atomically.

    The store is written into a temporary sibling folder and renamed into place, so a
    reader never sees half a store. ``path`` may not be the map's own source; an
    existing ``path`` is replaced (``overwrite``) only when it is a zarr store. Embeddings are copied one stored chunk at a time and
    are never held whole in memory; values are kept as stored (``normalize`` is recorded,
    not applied).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> m = LatentMap(np.eye(4, dtype=np.float16), kind="voxels", voxel_size=0.05)
    >>> p = write_zarr_map(m, os.path.join(tempfile.mkdtemp(), "m.zarr"))
    >>> from quash_plugins.adapters import read_map
    >>> str(read_map(p).embeddings.dtype)
    'float16'
    """
    zarr = require("zarr", "dask", "Zarr maps")
    path = Path(path).expanduser()
    refuse_own_input(path, lmap.source, folder=True)
    with atomic_dir(path, overwrite=overwrite) as tmp:
        group = zarr.open_group(str(tmp), mode="w", zarr_format=3)
        emb = lmap.embeddings
        dtype = np.dtype(emb.dtype)
        rows = max(1, min(lmap.n, store_chunk_rows(lmap.dim, dtype.itemsize, chunk_mb)))
        # Every chunk is written, even an all-zero one, so that a chunk missing from the
        # store later is known to be damage (see check_chunks).
        full = {"write_empty_chunks": True}
        z = group.create_array(
            "embeddings",
            shape=(lmap.n, lmap.dim),
            chunks=(rows, lmap.dim),
            dtype=dtype,
            config=full,
        )
        with progress(lmap.n, f"writing {path.name}") as advance:
            for start in range(0, lmap.n, rows):
                stop = min(lmap.n, start + rows)
                z[start:stop] = np.asarray(emb[start:stop], dtype=dtype)
                advance(stop - start)
        for key in ROW_ARRAYS:
            value = getattr(lmap, key)
            if value is not None:
                value = np.asarray(value)
                step = max(1, min(lmap.n, rows * 4))
                group.create_array(key, data=value, chunks=(step, *value.shape[1:]), config=full)
        group.attrs.update(
            {
                "quash_map": FORMAT_VERSION,
                "chunks_complete": True,
                "kind": lmap.kind,
                "voxel_size": lmap.voxel_size,
                "normalize": bool(lmap.normalize),
                "label_names": list(lmap.label_names) if lmap.label_names is not None else None,
                "frames": [asdict(f) for f in lmap.frames] if lmap.frames else None,
                "source": {
                    k: v for k, v in lmap.source.items() if isinstance(v, (str, int, float))
                },
            }
        )
    log.info("wrote %s: %d x %d %s in chunks of %d rows", path, lmap.n, lmap.dim, dtype, rows)
    return path


def missing_chunks(array: Any, root: Path, limit: int = 3) -> tuple[int, int, list[tuple]]:
    """``(missing, total, first)``: chunks of ``array`` absent from its store.

    ``first`` holds the grid coordinates of up to ``limit`` missing chunks, found by
    checking each chunk's key in a local store (other stores give the count only).
    """
    total = int(array.nchunks)
    try:
        stored = int(array.nchunks_initialized)
    except Exception:  # noqa: BLE001 - a store that cannot be listed: nothing to compare
        return 0, total, []
    if getattr(array, "shards", None) is not None or stored >= total:
        return 0, total, []
    first: list[tuple] = []
    folder = root / array.path if array.path else root
    if folder.is_dir():
        import itertools

        for coords in itertools.product(*(range(n) for n in array.cdata_shape)):
            if not (folder / array.metadata.encode_chunk_key(coords)).exists():
                first.append(coords)
                if len(first) >= limit:
                    break
    return total - stored, total, first


def check_chunks(array: Any, path: Path, name: str, complete: bool) -> None:
    """Refuse (``complete``) or warn about chunks missing from a zarr array's store."""
    missing, total, first = missing_chunks(array, path)
    if not missing:
        return
    rows = array.chunks[0]
    where = ", ".join(
        f"{array.metadata.encode_chunk_key(c)} (rows {c[0] * rows}-"
        f"{min(array.shape[0], (c[0] + 1) * rows) - 1})"
        for c in first
    )
    what = f"{missing} of {total} chunks of {name!r} are missing from the store"
    what += f", e.g. {where}" if where else ""
    if complete:
        raise MapFormatError(
            f"{path}: {what}. The store was written whole, so it is damaged (a chunk file was "
            "deleted or not copied). Copy it again or convert the original map again with "
            "`quash convert SRC DST.zarr`."
        )
    share = 100.0 * missing / max(1, total)
    log.warning(
        "%s: %s; zarr reads them as the fill value (%s), so about %.1f%% of the rows will "
        "count as unobserved and never match. If the store was copied or is damaged, "
        "convert the original map again.",
        path,
        what,
        array.fill_value,
        share,
    )


def read_zarr_map(path: str | Path, *, dask: bool = False, chunk_rows: int | None = None):
    """Open a zarr map lazily. ``dask=True`` gives ``da.from_zarr`` embeddings.

    A bare 2-D zarr array (not a group) is read as an embeddings-only map.
    """
    zarr = require("zarr", "dask", "Zarr maps")
    path = Path(path)
    try:
        # by its absolute path: the array pickles with its store's path, and a Dask
        # worker whose working directory is not this process's would read another
        # folder (or none: zarr reads a missing chunk as zeros, a map never observed)
        node = zarr.open(str(path.absolute()), mode="r")
    except Exception as exc:  # noqa: BLE001 - zarr raises many types for a bad store
        raise MapFormatError(f"{path}: not a readable zarr store ({exc}).") from None
    attrs: dict[str, Any] = {}
    if isinstance(node, zarr.Array):
        emb = node
    else:
        with warnings.catch_warnings():
            # zarr warns of a folder without metadata; the error below says it in words
            warnings.simplefilter("ignore", UserWarning)
            has_embeddings = "embeddings" in node
            found = ", ".join(sorted(node.keys())) or "nothing"
        if not has_embeddings:
            folder = path / "embeddings"
            if folder.is_dir():  # the array's data is there, its metadata is not
                meta = ", ".join(sorted(p.name for p in folder.iterdir() if p.is_file()))
                raise MapFormatError(
                    f"{path}: the folder 'embeddings' holds no zarr array metadata "
                    f"(embeddings/zarr.json for zarr 3, embeddings/.zarray for zarr 2; it has "
                    f"{meta or 'no files'}): the store is incomplete or damaged. Write it "
                    "again with `quash convert SRC DST.zarr`."
                )
            hint = result_hint(node.keys(), dict(node.attrs).get("map_source"))
            raise MapFormatError(
                f"{path}: missing array 'embeddings' (N, D). Found: {found}."
                + (hint or " Write maps with `quash convert SRC DST.zarr`.")
            )
        emb = node["embeddings"]
        attrs = dict(node.attrs)
    if len(emb.shape) != 2:
        raise MapFormatError(f"{path}: 'embeddings' must be 2-D (N, D); got shape {emb.shape}.")
    complete = bool(attrs.get("chunks_complete"))
    check_chunks(emb, path, "embeddings", complete)
    if not isinstance(node, zarr.Array):
        for key in ROW_ARRAYS:
            if key in node and complete:
                check_chunks(node[key], path, key, complete)
    if dask:
        import dask.array as da

        rows = chunk_rows or emb.chunks[0]
        emb = da.from_zarr(emb, chunks=(rows, emb.shape[1]))
    rows_data = {}
    if attrs or not isinstance(node, zarr.Array):
        for key in ROW_ARRAYS:
            if key in node:
                rows_data[key] = np.asarray(node[key][...])
    frames = attrs.get("frames")
    voxel = attrs.get("voxel_size")
    kind = attrs.get("kind") or ("voxels" if voxel else "points")
    return LatentMap(
        embeddings=emb,
        kind=kind,
        label_names=attrs.get("label_names"),
        voxel_size=float(voxel) if voxel is not None else None,
        frames=[FrameInfo(**f) for f in frames] if frames else None,
        normalize=bool(attrs.get("normalize", False)),
        source=record_inputs(  # the store: every member read is in it
            {
                **{k: v for k, v in dict(attrs.get("source") or {}).items() if k != SOURCE_INPUTS},
                "adapter": "zarr",
                "path": str(path),
            }
        ),
        **rows_data,
    )
