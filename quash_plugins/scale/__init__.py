"""Scale-out on Dask: classify maps larger than one machine, chunk by chunk.

- :func:`classify_dask` is the ``backend="dask"`` pass of :class:`~quash_plugins.Quash`:
  one ``map_blocks`` over row chunks scores every query at once, with the fitted
  classifiers shipped to the workers once.
- :func:`query_lazy` / :func:`query_to_zarr` keep masks and scores as dask arrays and
  write them to zarr, for maps whose results should not be gathered in memory.
- :func:`as_dask` wraps any map's embeddings (numpy, memmap, h5py, zarr, dask) as a
  row-chunked dask array; :func:`write_zarr_map` writes the zarr map store read by the
  ``zarr`` adapter.
- :func:`client_from_cli` turns ``--scheduler ADDRESS`` (or none: a LocalCluster) into a
  ``dask.distributed.Client``.

Nothing here imports dask or zarr until a function is called. See ``docs/scale.md``.
"""

from __future__ import annotations

from ._arrays import H5Rows, MemmapRows, as_dask, prepared_blocks
from ._classify import ClusterError, FittedClassifiers, classify_dask, scores_graph
from ._client import client_from_cli, local_cluster_client
from ._lazy import LazyQuery, postprocess_kind, query_lazy, query_to_zarr
from ._zarr_store import read_zarr_map, write_zarr_map

__all__ = [
    "ClusterError",
    "FittedClassifiers",
    "H5Rows",
    "LazyQuery",
    "MemmapRows",
    "as_dask",
    "classify_dask",
    "client_from_cli",
    "local_cluster_client",
    "postprocess_kind",
    "prepared_blocks",
    "query_lazy",
    "query_to_zarr",
    "read_zarr_map",
    "scores_graph",
    "write_zarr_map",
]
