"""The engine: one pipeline from a query to a labelled map.

:class:`Quash` expands a query with a heuristic, encodes it, fits a classifier and runs
one fused pass over the map (:func:`classify_local`, or :func:`classify_dask` on a Dask
cluster; both run :class:`BlockScorer`: one GEMM per block for every query, the map
never written), or, with ``device: cuda`` (or ``auto`` on a GPU machine), the GPU pass of
:mod:`quash_plugins.engine.device` on a map kept on the device. Refinement, instance
grouping, the text-embedding cache and the result writers live here too.

Rule: the engine imports :mod:`quash_plugins.core` only; plugins are reached through the
registry, never imported. Dask and zarr are imported when a function needs them.

- :func:`classify_dask` is the ``backend="dask"`` pass: one ``map_blocks`` over row
  chunks scores every query at once, with the fitted classifiers shipped once.
- :func:`query_to_zarr` (``LazyQuery.to_zarr``) writes ``query_many``'s masks and
  scores to zarr, for maps whose results should not be gathered in memory: fully lazy
  without ``refine`` and ``presence``, else in groups of queries that apply them;
  :func:`query_lazy` gives the first pass as dask arrays.
- :func:`as_dask` wraps any map's embeddings (numpy, memmap, h5py, zarr, dask) as a
  row-chunked dask array.
- :func:`client_from_cli` turns ``--scheduler ADDRESS`` (or none: a LocalCluster) into a
  ``dask.distributed.Client``.

See ``docs/architecture.md`` and ``docs/scale.md``.
"""

from __future__ import annotations

from ..core.optional import lazy_exports

_EXPORTS = {
    "Quash": ".pipeline",
    "build_quash": ".build",
    "classify_local": ".classify",
    "TextEmbeddingCache": ".cache",
    "default_cache_dir": ".cache",
    "open_cache": ".cache",
    "write_results_npz": ".results",
    "training_set": ".training",
    "find_instances": ".instances",
    "RefineOptions": ".refine",
    "H5Rows": ".dask_arrays",
    "MemmapRows": ".dask_arrays",
    "as_dask": ".dask_arrays",
    "prepared_blocks": ".dask_arrays",
    "ClusterError": ".dask_executor",
    "BlockScorer": ".classify",
    "classify_dask": ".dask_executor",
    "scores_graph": ".dask_executor",
    "client_from_cli": ".dask_client",
    "local_cluster_client": ".dask_client",
    "LazyQuery": ".lazy_query",
    "postprocess_kind": ".lazy_query",
    "query_lazy": ".lazy_query",
    "query_to_zarr": ".lazy_query",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
