"""The worker plugin of a LocalCluster quash starts (imported only with dask.distributed,
so that importing the engine stays light)."""

from __future__ import annotations

from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

from .dask_client import quiet_compute_failures


class QuietComputeFailures(WorkerPlugin):
    """Installs :class:`~quash_plugins.engine.dask_client._OwnComputeFailures` on each
    worker, those the nanny restarts included."""

    name = "quash-quiet-compute-failures"

    def setup(self, worker: Any) -> None:
        quiet_compute_failures()
