"""Compute-backend options shared by query, eval and demo (owned by the scale module).

``--backend dask`` runs the classification pass as ``map_blocks`` over row chunks on a
Dask cluster: the one at ``--scheduler ADDRESS``, or else a LocalCluster of worker
processes on 127.0.0.1 (``--workers N``, default one per core). See docs/scale.md.
"""

from __future__ import annotations

import argparse
import logging
from typing import Any

log = logging.getLogger(__name__)


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("compute backend")
    g.add_argument(
        "--backend",
        choices=("numpy", "dask"),
        default="numpy",
        help="numpy: in-process chunks (default); dask: map_blocks on a Dask cluster.",
    )
    g.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        default=None,
        help="Dask scheduler address (tcp://host:8786); implies --backend dask. "
        "Default: start a LocalCluster on this machine.",
    )
    g.add_argument(
        "--workers",
        metavar="N",
        type=int,
        default=None,
        help="Worker processes of the LocalCluster (default: one per core).",
    )


def backend_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword overrides for :meth:`Quash.from_config` from the parsed options."""
    from ..core.errors import UsageError

    backend = getattr(args, "backend", "numpy")
    address = getattr(args, "scheduler", None)
    workers = getattr(args, "workers", None)
    if address and backend != "dask":
        log.info("--scheduler given: using --backend dask")
        backend = "dask"
    if backend != "dask":
        if workers is not None:
            raise UsageError(
                f"--workers {workers} needs --backend dask: add --backend dask to run on a "
                "local Dask cluster, or leave out --workers."
            )
        return {}
    if workers is not None and address:
        raise UsageError(
            f"--workers {workers} starts a local cluster, --scheduler {address} uses a "
            "running one: give only one of them (the running cluster's workers are its "
            "own: `dask worker ADDRESS --nworkers N`)."
        )
    if workers is not None and workers < 1:
        raise UsageError(
            f"--workers {workers}: the local cluster needs at least one worker process. "
            "Give --workers N with N >= 1, or leave it out for one per core."
        )
    from ..engine import client_from_cli, local_cluster_client

    client = local_cluster_client(workers) if workers else client_from_cli(address)
    return {"backend": "dask", "client": client}
