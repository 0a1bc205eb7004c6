"""What the Dask pass tests share: orthonormal word vectors for a table encoder, a Quash
on them with several chunks per small map, and one worker process of the package's own
LocalCluster (as ``--backend dask`` starts it: every task and the graph are really
pickled and unpickled)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np

WORDS = ["chair", "sofa", "table", "other", "background", "nothing"]


def words(d: int, seed: int = 3) -> dict[str, np.ndarray]:
    """Each of :data:`WORDS` as a row of a random ``d x d`` orthonormal matrix."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(d, d)))
    return {w: q[i].astype(np.float32) for i, w in enumerate(WORDS)}


def table_quash(vecs: dict[str, np.ndarray], **kw: Any) -> Any:
    """A Quash of a table encoder on ``vecs``, contrast, no instances, and 0.05 MB
    chunks: several chunks on these small maps."""
    from quash_plugins import Quash
    from quash_plugins.core import registry
    from quash_plugins.encoders import TableEncoder

    return Quash(
        TableEncoder(table={w: v.tolist() for w, v in vecs.items()}),
        classifier=registry.create("classifiers", "contrast"),
        instances=None,
        chunk_mb=0.05,
        **kw,
    )


def one_worker_client() -> Iterator[Any]:
    """A client of a one-worker LocalCluster, closed afterwards (a fixture's body)."""
    from quash_plugins.engine.dask_client import close_started_clients, local_cluster_client

    c = local_cluster_client(n_workers=1, threads_per_worker=2, memory_limit="2GiB")
    yield c
    close_started_clients()
