"""The dask backend on a real ``dask.distributed`` LocalCluster of worker processes.

Results must equal the in-memory path (masks equal, scores within 1e-5), classifiers
travel to the workers once, a killed worker never yields a partial mask, and a worker's
memory stays bounded by the chunk size.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time

import distributed
import numpy as np
import pytest
import zarr  # noqa: F401 - the zarr writer is tested here

from quash_plugins import Quash
from quash_plugins.adapters import read_map, write_zarr_map
from quash_plugins.core import registry
from quash_plugins.core.errors import QuashError
from quash_plugins.core.types import LatentMap
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine import ClusterError, classify_dask, query_to_zarr, scores_graph

N, D = 300_000, 32
WORDS = ["chair", "sofa", "table", "other", "background", "nothing"]
CHUNK_MB = 2.0
Contrast = registry.load("classifiers", "contrast")


class MinMaxContrast(Contrast):
    """Contrast with a map-level min-max rescale (like ConceptFusion's relative rule)."""

    def decision_function(self, E):
        return super().decision_function(E) + np.float32(0.5)

    def postprocess_scores(self, scores):
        s = np.asarray(scores, np.float32)
        return ((s - s.min()) / max(float(s.max() - s.min()), 1e-12) - 0.6).astype(np.float32)


class ZScoreContrast(Contrast):
    """Contrast with a z-score postprocess: depends on mean and std, not only min/max."""

    def postprocess_scores(self, scores):
        s = np.asarray(scores, np.float64)
        return ((s - s.mean()) / (s.std() + 1e-12) - 0.5).astype(np.float32)


class CountingContrast(Contrast):
    """Counts how often it is unpickled, in the process that unpickles it."""

    def __setstate__(self, state):
        sys._quash_unpickled = getattr(sys, "_quash_unpickled", 0) + 1
        self.__dict__.update(state)


class SlowContrast(Contrast):
    """Sleeps in every chunk, so that a worker can be killed mid-query."""

    def __init__(self, delay: float = 0.15):
        self.delay = delay

    def decision_function(self, E):
        time.sleep(self.delay)
        return super().decision_function(E)


class RssContrast(Contrast):
    """Records the worker's resident memory at every chunk."""

    def decision_function(self, E):
        import psutil

        rss = psutil.Process().memory_info().rss
        sys._quash_rss = [*getattr(sys, "_quash_rss", []), rss]
        return super().decision_function(E)


class SuicidalContrast(Contrast):
    """Kills the worker process that runs it (never the test process)."""

    def decision_function(self, E):
        try:
            distributed.get_worker()
        except ValueError:
            return super().decision_function(E)
        os._exit(1)


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address="127.0.0.1:0",
        memory_limit="1GiB",
    )
    c = distributed.Client(cluster)
    c.run(lambda: __import__("quash_plugins.engine") and __import__("sklearn.svm"))  # warm up
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    rng = np.random.default_rng(0)
    T = rng.normal(size=(len(WORDS), D)).astype(np.float32)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    labels = rng.integers(0, 3, size=N)
    E = T[labels] + 0.7 * rng.normal(size=(N, D)).astype(np.float32)
    E *= rng.uniform(0.5, 3.0, size=(N, 1)).astype(np.float32)  # not unit: normalize=True
    E[rng.random(N) < 0.01] = 0  # unobserved rows
    emb = E.astype(np.float16)
    path = tmp_path_factory.mktemp("zarr") / "map.zarr"
    write_zarr_map(
        LatentMap(emb, normalize=True, labels=labels, label_names=WORDS[:3]), path, chunk_mb=1.0
    )
    table = {w: T[i].tolist() for i, w in enumerate(WORDS)}
    return {"path": path, "emb": emb, "table": table, "dir": path.parent}


def _quash(world, clf, **kw):
    return Quash(
        TableEncoder(table=world["table"]), classifier=clf, instances=None, chunk_mb=CHUNK_MB, **kw
    )


_REFERENCES: dict = {}


def _reference(world, clf, texts=("chair", "sofa")):
    key = (repr(clf), type(clf).__name__, tuple(texts))
    if key not in _REFERENCES:
        _REFERENCES[key] = _reference_uncached(world, clf, texts)
    return _REFERENCES[key]


def _reference_uncached(world, clf, texts):
    lmap = LatentMap(world["emb"], normalize=True)  # fully in memory, numpy backend
    return _quash(world, clf).query_many(lmap, list(texts))


def _assert_same(results, expected):
    for r, e in zip(results, expected, strict=True):
        assert r.mask.shape == (N,)
        np.testing.assert_array_equal(r.mask, e.mask)
        np.testing.assert_allclose(r.scores, e.scores, atol=1e-5, rtol=0)
        assert np.isfinite(r.scores).all()


@pytest.mark.parametrize(
    ("name", "params", "as_dask_array"),
    [("contrast", {}, False), ("svm-rbf", {"C": 10.0, "class_weight": "balanced"}, True)],
)
def test_dask_backend_equals_in_memory(client, world, name, params, as_dask_array):
    clf = registry.create("classifiers", name, **params)
    expected = _reference(world, clf)
    assert 0 < expected[0].n_matched < N  # a meaningful comparison
    lmap = read_map(world["path"], dask=as_dask_array)
    results = _quash(world, clf, backend="dask", client=client).query_many(lmap, ["chair", "sofa"])
    _assert_same(results, expected)
    observed = np.linalg.norm(world["emb"].astype(np.float32), axis=1) > 0
    assert not results[0].mask[~observed].any()


def test_one_pass_for_several_queries(client, world):
    clfs = [_quash(world, None).fit(_quash(world, None).expand(t)) for t in ("chair", "sofa")]
    g = scores_graph(read_map(world["path"]), clfs, int(CHUNK_MB * 2**20), client)
    assert g.shape == (N, 3) and g.chunks[1] == (3,)
    # one classification task per row chunk, not one per (chunk, query)
    layers = g.dask.layers
    (top,) = [k for k in layers if k.startswith("quash-scores")]
    assert len(layers[top]) == g.numblocks[0]


def test_classifiers_shipped_once(client, world):
    client.run(lambda: setattr(sys, "_quash_unpickled", 0))
    clf = CountingContrast().fit(np.eye(4, D, dtype=np.float32), np.array([1, 0, 0, 0]))
    lmap = read_map(world["path"])
    scores, observed = classify_dask(lmap, [clf, clf], chunk_bytes=2**20, client=client)
    chunks = lmap.chunk_rows(2**20, 64)
    assert N // chunks > 20
    counts = client.run(lambda: getattr(sys, "_quash_unpickled", 0))
    assert all(c <= 1 for c in counts.values()), counts  # once per worker, not per chunk
    assert len(scores) == 2 and observed.sum() > 0.98 * N


@pytest.mark.parametrize("on", ["client", "threads"])
def test_progress_counts_every_row_once_as_chunks_finish(client, world, on):
    """``progress(rows)`` moves during a Dask pass (the bar of ``quash query`` with
    ``backend: dask``): one call per chunk, adding up to the map; the scores are those of
    a pass without it."""
    clf = registry.create("classifiers", "contrast")
    clf = _quash(world, clf).fit(_quash(world, clf).expand("chair"))
    lmap = read_map(world["path"])
    use = client if on == "client" else None
    calls: list[int] = []
    counted, observed = classify_dask(
        lmap, [clf], chunk_bytes=2**20, client=use, progress=calls.append
    )
    plain, _ = classify_dask(lmap, [clf], chunk_bytes=2**20, client=use)
    assert sum(calls) == N and len(calls) == len(scores_graph(lmap, [clf], 2**20).chunks[0])
    assert len(calls) > 1
    np.testing.assert_array_equal(counted[0], plain[0])
    assert observed.sum() > 0.98 * N


def test_a_corrupt_chunk_on_a_worker_names_the_rows_and_the_chunk(client, world, tmp_path):
    """A worker that fails to read a chunk: the error the client gets names the map,
    the rows and the zarr chunk file, not a cluster fault."""
    import shutil

    from quash_plugins.core.errors import MapFormatError

    path = tmp_path / "map.zarr"
    shutil.copytree(world["path"], path)
    chunk = sorted((path / "embeddings" / "c").iterdir())[1] / "0"
    chunk.write_bytes(b"garbage")
    lmap = read_map(path)
    rows = lmap.embeddings.chunks[0]
    clf = registry.create("classifiers", "contrast")
    quash = _quash(world, clf, backend="dask", client=client)
    with pytest.raises(MapFormatError) as err:
        quash.query_many(lmap, ["chair"])
    msg = str(err.value)
    key = f"embeddings/c/{chunk.parent.name}/0"
    assert str(path) in msg and f"zarr chunk {key})" in msg, msg
    # the rows named are those of the dask task that failed: they overlap the bad chunk
    import re

    a, b = map(int, re.search(r"rows (\d+)-(\d+) of the embeddings", msg).groups())
    first = int(chunk.parent.name) * rows
    assert a <= first + rows - 1 and b >= first, msg


@pytest.mark.parametrize("cls", [MinMaxContrast, ZScoreContrast])
def test_map_level_postprocess_lazy_and_eager(client, world, tmp_path, cls):
    from quash_plugins.engine import postprocess_kind

    assert postprocess_kind(cls()) == ("minmax" if cls is MinMaxContrast else "global")
    expected = _reference(world, cls())
    assert 0 < expected[0].n_matched < N
    q = _quash(world, cls(), backend="dask", client=client)
    _assert_same(q.query_many(world["path"], ["chair", "sofa"]), expected)
    lazy = q.query_many_lazy(world["path"], ["chair", "sofa"])
    assert lazy.masks.shape == (2, N) and lazy.scores.dtype == np.float32  # still lazy
    scores, masks, observed = lazy.compute()
    for i, e in enumerate(expected):
        np.testing.assert_array_equal(masks[i], e.mask)
        np.testing.assert_allclose(scores[i], e.scores, atol=1e-5, rtol=0)
    out = query_to_zarr(q, world["path"], ["chair", "sofa"], tmp_path / "res.zarr", client)

    g = zarr.open_group(str(out), mode="r")
    assert g.attrs["queries"] == ["chair", "sofa"] and "_raw" not in g
    for i, e in enumerate(expected):
        np.testing.assert_array_equal(g["masks"][i], e.mask)
        np.testing.assert_allclose(g["scores"][i], e.scores, atol=1e-5, rtol=0)
    np.testing.assert_array_equal(g["observed"][:], observed)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["res.zarr"]


def test_memory_per_worker_bounded_by_chunk(client, world):
    client.run(lambda: setattr(sys, "_quash_rss", []))
    clf = RssContrast().fit(np.eye(4, D, dtype=np.float32), np.array([1, 0, 0, 0]))
    chunk_bytes = 2**20
    lmap = read_map(world["path"])
    g = scores_graph(lmap, [clf], chunk_bytes, client)
    assert max(g.chunks[0]) * D * 4 <= chunk_bytes  # every task's float32 block fits
    classify_dask(lmap, [clf], chunk_bytes=chunk_bytes, client=client)
    samples = [s for s in client.run(lambda: getattr(sys, "_quash_rss", [])).values() if s]
    growth = max(max(s) - s[0] for s in samples)
    map_f32 = N * D * 4  # 38 MB: what a worker would hold if it loaded the map
    assert growth < map_f32 / 2, (growth, map_f32)


def test_worker_killed_mid_query(client, world):
    expected = _reference(world, Contrast())
    q = _quash(world, SlowContrast(delay=0.15), backend="dask", client=client)
    outcome: dict = {}

    def run():
        try:
            outcome["results"] = q.query_many(world["path"], ["chair", "sofa"])
        except QuashError as exc:
            outcome["error"] = exc

    t = threading.Thread(target=run)
    t.start()
    deadline = time.time() + 60
    while time.time() < deadline and not any(client.processing().values()):
        time.sleep(0.05)
    time.sleep(0.5)  # some chunks are done, others in flight
    pids = client.run(os.getpid)
    victim = sorted(pids.values())[0]
    os.kill(victim, signal.SIGKILL)
    t.join(180)
    assert not t.is_alive()
    if "results" in outcome:  # recomputed on the surviving / restarted worker
        _assert_same(outcome["results"], expected)
    else:  # or a clear error, never a partial mask
        assert "Dask cluster" in str(outcome["error"])
    client.wait_for_workers(2, timeout=60)
    assert victim not in client.run(os.getpid).values()


@pytest.mark.slow
def test_failing_workers_raise_a_clear_error(world):
    import dask

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        cluster = distributed.LocalCluster(
            n_workers=1,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address="127.0.0.1:0",
        )
        c = distributed.Client(cluster)
    try:
        q = _quash(world, SuicidalContrast(), backend="dask", client=c)
        with pytest.raises(ClusterError, match="Dask cluster failed") as info:
            q.query(world["path"], "chair")
        assert isinstance(info.value, QuashError)
    finally:
        c.close()
        cluster.close()


def test_cli_query_zarr_with_dask_backend(client, world, tmp_path, capsys):
    import json

    from quash_plugins.cli.main import main

    table = tmp_path / "text.npz"
    np.savez(table, texts=np.asarray(WORDS), embeddings=np.asarray(list(world["table"].values())))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        f"encoder: {{name: table, file: {table}}}\nclassifier: contrast\n"
        "instances: null\nchunk_mb: 2\n"
    )
    addr = client.scheduler.address
    rc = main(
        [
            "query",
            str(world["path"]),
            "chair",
            "-c",
            str(cfg),
            "--backend",
            "dask",
            "--scheduler",
            addr,
            "--json",
            "--out",
            str(tmp_path / "r.npz"),
        ]
    )
    cli_client = distributed.default_client()
    if cli_client is not client:
        cli_client.close()  # the CLI's own connection to the scheduler
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    expected = _reference(world, Contrast(), texts=("chair",))[0]
    assert doc["results"][0]["matched"] == expected.n_matched
    with np.load(tmp_path / "r.npz") as z:
        np.testing.assert_array_equal(z["masks"][0], expected.mask)


def test_cli_convert_to_zarr(tmp_path, world):
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main

    emb = world["emb"][:1000]
    src = write_npz_map(LatentMap(emb, normalize=True), tmp_path / "m.npz")
    assert main(["convert", str(src), str(tmp_path / "m.zarr")]) == 0
    back = read_map(tmp_path / "m.zarr")
    assert back.embeddings.dtype == np.float16 and back.normalize
    np.testing.assert_array_equal(np.asarray(back.embeddings[...]), emb)


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("svm-rbf", {"C": 10.0}),
        ("nearest-sample", {"k": 2}),
        ("sklearn", {"estimator": "sklearn.linear_model.LogisticRegression"}),
    ],
)
def test_masks_equal_at_the_threshold_itself(client, world, name, params):
    """The issue's case: scores within a hair of the threshold, many rows. The executors
    share BlockScorer, chunk rows and the cast, so scores are equal bit for bit; with the
    threshold set to a score the map really has, any difference would flip a mask."""
    clf = registry.create("classifiers", name, **params)
    reference = _reference(world, clf)[0]
    observed = np.linalg.norm(world["emb"].astype(np.float32), axis=1) > 0
    at = np.sort(reference.scores[observed])
    for threshold in (float(at[len(at) // 2]), float(at[len(at) // 3])):
        local = _quash(world, clf, threshold=threshold).query_many(
            LatentMap(world["emb"], normalize=True), ["chair"]
        )[0]
        remote = _quash(world, clf, threshold=threshold, backend="dask", client=client)
        dask_result = remote.query_many(read_map(world["path"]), ["chair"])[0]
        assert (local.scores == threshold).any()  # rows sit exactly on the threshold
        np.testing.assert_array_equal(dask_result.scores, local.scores)
        np.testing.assert_array_equal(dask_result.mask, local.mask)


@pytest.mark.parametrize("on", ["client", "threads"])
def test_to_zarr_without_refine_shows_progress_of_the_map_pass(
    client, world, tmp_path, monkeypatch, on
):
    """The fully lazy ``--out RESULT.zarr`` path (no refine, no presence) reads the whole
    map in one pass: it moves a progress bar chunk by chunk, adding up to the map, as
    ``quash query`` without ``--out`` does; the store is the in-memory answer."""
    import contextlib

    import quash_plugins.core.progress as progress_module

    bars: list[tuple[int, str, list[int]]] = []

    @contextlib.contextmanager
    def recorded(total, what):
        calls: list[int] = []
        bars.append((total, what, calls))
        yield calls.append

    monkeypatch.setattr(progress_module, "progress", recorded)
    expected = _reference(world, MinMaxContrast())
    use = client if on == "client" else None  # None: local threads
    q = _quash(world, MinMaxContrast(), backend="dask", client=use)
    lazy = q.query_many_lazy(world["path"], ["chair", "sofa"])
    out = lazy.to_zarr(tmp_path / "res.zarr")
    (bar,) = [b for b in bars if b[0] == N and "scoring 2 queries" in b[1]]
    moved = [n for n in bar[2] if n]
    assert sum(moved) == N and len(moved) == lazy.raw.numblocks[0] > 1
    g = zarr.open_group(str(out), mode="r")
    for i, e in enumerate(expected):
        np.testing.assert_array_equal(g["masks"][i], e.mask)
        np.testing.assert_allclose(g["scores"][i], e.scores, atol=1e-5, rtol=0)


def test_relative_paths_with_workers_in_another_directory(client, world, tmp_path, monkeypatch):
    """A scheduler started elsewhere: its workers' working directory is not the
    client's. A relative map path and a relative ``--out`` still read the map and write
    the store the client names (they used to read a missing store as zeros, a map never
    observed, and write the results into the workers' own directory: an empty answer)."""
    elsewhere = tmp_path / "workers-cwd"
    elsewhere.mkdir()
    before = client.run(os.getcwd)
    client.run(os.chdir, str(elsewhere))
    try:
        monkeypatch.chdir(world["dir"])
        expected = _reference(world, MinMaxContrast())
        q = _quash(world, MinMaxContrast(), backend="dask", client=client)
        rel_map = world["path"].name
        results = q.query_many(rel_map, ["chair", "sofa"])
        _assert_same(results, expected)
        out_rel = os.path.relpath(tmp_path / "res.zarr", world["dir"])
        out = query_to_zarr(q, rel_map, ["chair", "sofa"], out_rel, client)
        assert str(out) == out_rel  # the path as the caller gave it
        g = zarr.open_group(str(tmp_path / "res.zarr"), mode="r")
        for i, e in enumerate(expected):
            np.testing.assert_array_equal(g["masks"][i], e.mask)
        assert list(elsewhere.iterdir()) == []  # nothing written where the workers run
    finally:
        for addr, cwd in before.items():
            client.run(os.chdir, cwd, workers=[addr])


def test_a_worker_without_the_map_store_says_so(world, tmp_path):
    """A worker that does not see the map's store (no shared file system) fails naming
    the store and the fix; zarr alone would read every chunk as zeros."""
    import shutil

    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.engine.dask_arrays import ZarrRows

    path = tmp_path / "map.zarr"
    shutil.copytree(world["path"], path)
    lmap = read_map(path)
    reader = ZarrRows(lmap.embeddings, str(path), "zarr")
    assert np.abs(reader[0:10]).sum() > 0  # there: the stored rows
    shutil.rmtree(path)
    with pytest.raises(MapFormatError, match=r"same path on every worker.*--scheduler"):
        reader[0:10]


def test_results_written_where_the_client_cannot_see_them_are_an_error(
    world, tmp_path, monkeypatch
):
    """Workers that write the result chunks to a file system of their own leave the
    client's store without them: the query fails naming the fix, and leaves no store
    (it used to be renamed into place with its scores missing)."""
    from quash_plugins.core.errors import UsageError
    from quash_plugins.engine import lazy_query

    def lost(block, zarr_array, block_info=None):  # writes nowhere this process sees
        a, b = block_info[0]["array-location"][0]
        return np.array([b - a], np.int64)

    monkeypatch.setattr(lazy_query, "_store_rows", lost)
    q = _quash(world, MinMaxContrast())
    with pytest.raises(UsageError, match=r"storage the\s+workers share"):
        query_to_zarr(q, world["path"], ["chair"], tmp_path / "res.zarr")
    assert list(tmp_path.iterdir()) == []


def test_a_zarr_map_read_by_a_relative_path_travels_by_its_absolute_one(
    world, tmp_path, monkeypatch
):
    """The embeddings of a map read as ``map.zarr`` pickle with the store's absolute
    path: a worker whose working directory is another folder reads the map's rows (a
    relative store read nothing there: every chunk came back as zeros)."""
    import pickle

    monkeypatch.chdir(world["dir"])
    emb = read_map(world["path"].name).embeddings
    monkeypatch.chdir(tmp_path)  # a worker started elsewhere
    again = pickle.loads(pickle.dumps(emb))
    np.testing.assert_array_equal(np.asarray(again[:100]), world["emb"][:100])


def test_the_pass_log_names_the_scheduler_address(client, world, caplog):
    """The 'dask pass' line names where the pass runs by the scheduler's address, not
    by the repr of the client's connection pool ('<pooled rpc to ...>')."""
    import logging

    clf = Contrast().fit(np.eye(4, D, dtype=np.float32), np.array([1, 0, 0, 0]))
    lmap = read_map(world["path"])
    with caplog.at_level(logging.INFO, logger="quash_plugins.engine.dask_executor"):
        classify_dask(lmap, [clf], chunk_bytes=2**22, client=client)
    (line,) = [r.getMessage() for r in caplog.records if r.getMessage().startswith("dask pass")]
    assert line.endswith(f"the scheduler at {client.scheduler.address}"), line
    assert "pooled rpc" not in line


def test_a_scheduler_of_other_versions_is_said_as_such(world):
    """A scheduler started from another environment (or before quash-plugins changed)
    cannot unpickle the tasks: a ClusterError that says so and how to fix it, not a
    'damaged map' error (the pass's read errors are the map's) nor Dask's bare
    RuntimeError."""
    from quash_plugins.engine.dask_executor import compute

    class SkewedClient:
        scheduler = None

        def compute(self, *args, **kwargs):
            raise RuntimeError(
                "Error during deserialization of the task graph. This frequently occurs "
                "if the Scheduler and Client have different environments."
            )

    clf = Contrast().fit(np.eye(4, D, dtype=np.float32), np.array([1, 0, 0, 0]))
    lmap = read_map(world["path"])
    with pytest.raises(ClusterError, match=r"other versions.*Restart the scheduler"):
        classify_dask(lmap, [clf], chunk_bytes=2**22, client=SkewedClient())
    with pytest.raises(ClusterError, match="Restart the scheduler"):
        compute(SkewedClient(), scores_graph(lmap, [clf], 2**22))
