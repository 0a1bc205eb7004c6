"""Ctrl-C while the local Dask cluster starts: one line, exit status 130, no worker left.

A terminal sends Ctrl-C to the whole process group: each worker process used to print a
traceback of its own, and Dask's exit handler another one for the half-started cluster.
The cluster now starts from a thread that blocks SIGINT (inherited by every thread and
worker process it starts); the command closes the cluster and says "interrupted".
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

pytest.importorskip("distributed")
psutil = pytest.importorskip("psutil")

from quash_plugins.engine import dask_client  # noqa: E402

needs_sigmask = pytest.mark.skipif(
    not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks"
)


@needs_sigmask
def test_ctrl_c_while_the_cluster_starts_closes_it_and_is_raised(monkeypatch):
    import distributed

    made = []

    class SlowCluster:
        """Receives Ctrl-C in the middle of its start, as a LocalCluster would."""

        def __init__(self, **kwargs):
            self.sigint_blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
            self.closed = False
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.5)  # the start goes on
            made.append(self)

        def close(self):
            self.closed = True

    monkeypatch.setattr(distributed, "LocalCluster", SlowCluster)
    started = list(dask_client._STARTED)
    with pytest.raises(KeyboardInterrupt):
        dask_client.local_cluster_client(1)
    assert len(made) == 1
    assert made[0].sigint_blocked  # so the threads and workers it starts ignore Ctrl-C
    assert made[0].closed
    assert started == dask_client._STARTED


@needs_sigmask
def test_a_second_ctrl_c_leaves_the_start_thread_to_close_the_cluster(monkeypatch):
    """A second Ctrl-C stops the wait for the start; the cluster was then closed only if
    it had already started (outcome["value"] was still None), so one that finished its
    start afterwards kept its worker processes until the interpreter exited."""
    waiting = threading.Event()  # the caller waits again after the first Ctrl-C
    release = threading.Event()  # the start ends once the caller has given up
    made = []

    class SlowCluster:
        def __init__(self, **kwargs):
            self.closed = False
            os.kill(os.getpid(), signal.SIGINT)
            assert waiting.wait(10)
            time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGINT)  # the second Ctrl-C
            assert release.wait(10)
            made.append(self)

        def close(self):
            self.closed = True

    def debug(msg, *args):
        if msg.startswith("interrupted while the local Dask cluster starts"):
            waiting.set()

    monkeypatch.setattr(dask_client.log, "debug", debug)
    with pytest.raises(KeyboardInterrupt):
        dask_client._start_without_sigint(SlowCluster)
    assert made == []  # the caller stopped waiting before the start ended
    release.set()
    deadline = time.monotonic() + 10
    while not (made and made[0].closed) and time.monotonic() < deadline:
        time.sleep(0.02)
    assert len(made) == 1
    assert made[0].closed


@needs_sigmask
def test_a_failed_start_is_raised_as_it_was(monkeypatch):
    import distributed

    def fail(**kwargs):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", fail)
    with pytest.raises(RuntimeError, match="Nanny failed to start"):
        dask_client.local_cluster_client(1)


def _workers(proc):
    try:
        children = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    out = []
    for c in children:
        try:
            if "spawn_main" in " ".join(c.cmdline()):
                out.append(c)
        except psutil.Error:
            pass
    return out


@needs_sigmask
def test_ctrl_c_of_a_real_query_while_its_cluster_starts(tmp_path):
    """``quash query --backend dask``, Ctrl-C to its process group once the first worker
    process exists (the cluster waits for it to register): one line, 130, nothing left."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    scene = write_npz_map(
        LatentMap(np.eye(64, 8, dtype=np.float32), positions=np.zeros((64, 3))),
        tmp_path / "scene.npz",
    )
    config = tmp_path / "c.yaml"
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0], "
        "other: [0, 1, 0, 0, 0, 0, 0, 0]}}\nnegatives: [other]\ninstances: false\ncache: false\n"
    )
    cmd = [sys.executable, "-m", "quash_plugins.cli.main", "-q", "query", str(scene), "chair"]
    cmd += ["-c", str(config), "--backend", "dask", "--workers", "1"]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, text=True
    )
    try:
        deadline = time.monotonic() + 90
        while not _workers(proc):
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "no worker process started"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does
        _, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert (proc.returncode, err) == (130, "interrupted\n")
    deadline = time.monotonic() + 10
    while True:  # worker processes exit with the cluster (zombies wait for their reaper)
        left = [p for p in psutil.process_iter(["pid", "status"]) if _in_session(p, proc.pid)]
        if not left or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert left == []


def _in_session(p, sid: int) -> bool:
    try:
        return os.getsid(p.pid) == sid and p.status() != psutil.STATUS_ZOMBIE
    except (OSError, psutil.Error):
        return False


@needs_sigmask
def test_ctrl_c_of_a_real_query_mid_compute_says_one_line(tmp_path):
    """``quash query MAP.zarr chair --backend dask --out r.zarr``, Ctrl-C to its process
    group once the result store is being written: the workers (cancelled tasks,
    heartbeats to a closing scheduler) and the client (an abandoned wait's AllExit) used
    to print warnings and tracebacks under "interrupted". Now: that line only, 130, no
    process left and no temporary in place of the output."""
    from quash_plugins.adapters import convert_map, write_npz_map
    from quash_plugins.core.types import LatentMap

    rows = 3_000_000  # 96 MiB of embeddings: seconds of compute on a worker
    emb = np.zeros((rows, 8), dtype=np.float32)
    emb[::2, 0] = emb[1::2, 1] = 1
    npz = write_npz_map(LatentMap(emb, positions=np.zeros((rows, 3))), tmp_path / "s.npz")
    scene = convert_map(npz, tmp_path / "scene.zarr")
    npz.unlink()
    config = tmp_path / "c.yaml"
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0], "
        "other: [0, 1, 0, 0, 0, 0, 0, 0]}}\nnegatives: [other]\ninstances: false\n"
        "cache: false\nchunk_mb: 64\n"
    )
    out = tmp_path / "r.zarr"
    cmd = [sys.executable, "-m", "quash_plugins.cli.main", "-q", "query", str(scene), "chair"]
    cmd += ["-c", str(config), "--backend", "dask", "--workers", "1", "--out", str(out)]
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True, text=True
    )
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".r.zarr.quash-tmp-*")):  # the compute has begun
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the result store was never begun"
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert (proc.returncode, err) == (130, "interrupted\n")
    assert not out.exists()
    deadline = time.monotonic() + 10
    while True:
        left = [p for p in psutil.process_iter(["pid", "status"]) if _in_session(p, proc.pid)]
        if not left or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert left == []
    assert list(tmp_path.glob(".r.zarr.*")) == []  # no chunk a worker wrote late


def test_the_command_closes_its_clients_quietly_only_when_interrupted(monkeypatch):
    from quash_plugins.cli import main as cli

    seen = []
    monkeypatch.setattr(dask_client, "_STARTED", [])
    for stop in (KeyboardInterrupt, None):
        dask_client._STARTED.append(lambda quiet=False: seen.append(quiet))
        expect = pytest.raises(KeyboardInterrupt) if stop else contextlib.nullcontext()
        with expect, cli._dask_clients_closed():
            if stop:
                raise stop
    assert seen == [True, False]


def test_only_abandoned_waits_of_a_closed_client_are_dropped():
    import logging

    from distributed.client import AllExit

    def record(msg, exc):
        return logging.LogRecord(
            "asyncio", logging.ERROR, __file__, 1, msg, None, (type(exc), exc, None)
        )

    keep = dask_client._AbandonedWaits().filter
    assert not keep(record("Task exception was never retrieved\nfuture: ...", AllExit()))
    assert keep(record("Task exception was never retrieved\nfuture: ...", ValueError("x")))
    assert keep(record("Exception in callback ...", AllExit()))
