"""``zarr``: maps stored as zarr (written by ``quash convert SRC DST.zarr``), read lazily.

Embeddings stay on disk: a ``zarr.Array`` by default, or a dask array with ``dask: true``.
Other zarr stores work too: a group holding a 2-D ``embeddings`` array, or a bare 2-D
array (an embeddings-only map).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ..core.interfaces import MapAdapter
from ..core.types import LatentMap


def _is_array(meta: Path) -> bool:
    try:
        doc = json.loads(meta.read_text())
    except (OSError, ValueError):
        return False
    shape = doc.get("shape")
    is_array = doc.get("node_type", "array") == "array" or meta.name == ".zarray"
    return bool(is_array and isinstance(shape, list) and len(shape) == 2)


class ZarrAdapter(MapAdapter):
    """Read a zarr map store lazily.

    Parameters
    ----------
    dask
        Give the embeddings as a ``dask.array`` (``da.from_zarr``) instead of a
        ``zarr.Array``. Both are read chunk by chunk.
    chunk_rows
        Row chunking of the dask array (default: the store's chunks).
    """

    name = "zarr"
    priority = 10
    suffixes = (".zarr",)

    def __init__(self, dask: bool = False, chunk_rows: int | None = None) -> None:
        self.dask, self.chunk_rows = _checked_options(dask, chunk_rows)

    def sniff(self, source: Any) -> bool:
        if not isinstance(source, (str, Path)):
            return False
        p = Path(source)
        if not p.is_dir():
            return False
        for meta in ("zarr.json", ".zarray"):
            if (p / meta).is_file() and _is_array(p / meta):
                return True
        for meta in ("zarr.json", ".zarray"):
            if (p / "embeddings" / meta).is_file():
                return _is_array(p / "embeddings" / meta)
        return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        from ._zarr_store import read_zarr_map

        opts = self.options(options)
        opts["dask"], opts["chunk_rows"] = _checked_options(opts["dask"], opts["chunk_rows"])
        return read_zarr_map(Path(source), **opts)

    def write_example(self, directory: Path) -> Path:
        from ._zarr_store import write_zarr_map

        rng = np.random.default_rng(0)
        lmap = LatentMap(
            rng.normal(size=(40, 8)).astype(np.float16),
            kind="voxels",
            positions=rng.uniform(0, 2, size=(40, 3)).astype(np.float32),
            colors=rng.integers(0, 255, size=(40, 3), dtype=np.uint8),
            labels=rng.integers(0, 3, size=40),
            label_names=["floor", "chair", "table"],
            voxel_size=0.05,
        )
        return write_zarr_map(lmap, Path(directory) / "example.zarr")


def _checked_options(dask: Any, chunk_rows: Any) -> tuple[bool, int | None]:
    """The ``dask`` and ``chunk_rows`` options, refused (naming the option and what it
    takes) unless ``dask`` is true or false and ``chunk_rows`` a whole number >= 1 or
    null: a bad ``chunk_rows`` used to surface as a damaged file, and ``dask: ture`` was
    taken as true."""
    from ..core.errors import ConfigError

    if not isinstance(dask, bool):
        raise ConfigError(f"Adapter 'zarr': option 'dask' must be true or false; got {dask!r}.")
    if chunk_rows is not None and (
        isinstance(chunk_rows, bool) or not isinstance(chunk_rows, int) or chunk_rows < 1
    ):
        raise ConfigError(
            "Adapter 'zarr': option 'chunk_rows' must be a whole number of rows >= 1 (the "
            f"rows of a dask chunk), or null for the store's own chunks; got {chunk_rows!r}."
        )
    return dask, chunk_rows
