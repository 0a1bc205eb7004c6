"""A failed task of quash's own LocalCluster is said once, by the client, as one line
naming the file and the fix: the worker's "Compute Failed" record (the task's repr and
the traceback, at ERROR, which --quiet could not hide) is dropped for quash's tasks."""

from __future__ import annotations

import logging
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("distributed")
pytest.importorskip("zarr")

from quash_plugins.engine.dask_client import TASK_PREFIX, _OwnComputeFailures  # noqa: E402

FORMAT = "Compute Failed\nKey:       %s\nState:     %s\nTask:  %s\nException: %r\nTraceback: %r\n"


def _record(msg, args):
    return logging.LogRecord("distributed.worker", logging.ERROR, __file__, 1, msg, args, None)


def test_the_filter_drops_only_quash_tasks_compute_failures():
    keep = _OwnComputeFailures().filter
    ours = (f"{TASK_PREFIX}scores-0a1b", 0, 0)
    assert not keep(_record(FORMAT, (ours, "executing", "<Task>", "boom", "tb")))
    assert keep(_record(FORMAT, (("someone-elses-task", 0), "executing", "<Task>", "x", "tb")))
    assert keep(_record("Worker is at %d%% memory usage. Pausing worker.", (85,)))
    assert keep(_record("Compute Failed without arguments", ()))


@pytest.mark.slow
def test_quiet_cli_says_a_damaged_chunk_once_on_its_own_cluster(tmp_path):
    from quash_plugins.adapters import write_zarr_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(0)
    words = ["chair", "sofa", "table", "other", "background", "nothing"]
    vecs = rng.normal(size=(len(words), 8)).astype(np.float32)
    table = tmp_path / "text.npz"
    np.savez(table, texts=np.asarray(words), embeddings=vecs)
    lmap = LatentMap(
        rng.normal(size=(4000, 8)).astype(np.float32),
        positions=rng.uniform(0, 4, size=(4000, 3)).astype(np.float32),
    )
    store = write_zarr_map(lmap, tmp_path / "map.zarr")
    chunks = sorted(
        p for p in (store / "embeddings").rglob("*") if p.is_file() and p.stem != "zarr"
    )
    assert chunks, "the zarr writer's layout changed"
    chunks[0].write_bytes(chunks[0].read_bytes()[:40])  # a chunk cut short
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"encoder: {{name: table, file: {table}}}\nclassifier: contrast\n")
    done = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys; from quash_plugins.cli.main import main; sys.exit(main())",
            "-q",
            "query",
            str(store),
            "chair",
            "-c",
            str(cfg),
            "--backend",
            "dask",
            "--workers",
            "1",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 1, done.stdout + done.stderr
    assert "Compute Failed" not in done.stderr and "Traceback" not in done.stderr
    lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("quash query: error: "), done.stderr
    assert "map.zarr" in lines[0] and "embeddings" in lines[0]


def test_a_worker_restart_of_the_own_cluster_is_one_quash_warning(caplog):
    """A worker of quash's LocalCluster that dies is recovered by Dask; the scheduler's
    and the nanny's records of it (in distributed's own format, every lost task key) are
    replaced by one warning of quash's that says the result is unchanged, whatever the
    number of restarts. Errors pass."""
    from quash_plugins.engine.dask_client import _OwnWorkerRestarts

    keep = _OwnWorkerRestarts().filter

    def rec(name, level, msg):
        return logging.LogRecord(name, level, __file__, 1, msg, (), None)

    lost = "Removing worker 'tls://127.0.0.1:4' caused the cluster to lose already computed"
    with caplog.at_level(logging.WARNING, logger="quash_plugins"):
        assert not keep(rec("distributed.scheduler", logging.WARNING, lost))
        assert not keep(rec("distributed.nanny", logging.WARNING, "Restarting worker (x)"))
        assert not keep(rec("distributed.nanny", logging.INFO, "Worker process 7 was killed"))
        assert not keep(rec("distributed.scheduler", logging.WARNING, lost))
    ours = [r.getMessage() for r in caplog.records if r.name.startswith("quash_plugins")]
    assert len(ours) == 1 and "the result is unchanged" in ours[0]
    assert keep(rec("distributed.scheduler", logging.ERROR, "Removing worker: gave up"))
    assert keep(rec("distributed.scheduler", logging.WARNING, "Worker is at 85% memory"))


def test_the_own_cluster_installs_the_restart_filter_and_removes_it_on_close():
    from quash_plugins.engine import dask_client

    def installed():
        return [
            name
            for name in dask_client.RESTART_LOGGERS
            if any(
                isinstance(f, dask_client._OwnWorkerRestarts)
                for f in logging.getLogger(name).filters
            )
        ]

    client = dask_client.local_cluster_client(1)
    try:
        assert installed() == list(dask_client.RESTART_LOGGERS)
    finally:
        dask_client.close_started_clients()
    assert installed() == []
    assert client.status == "closed"
