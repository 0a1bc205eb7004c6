"""An in-memory map is scattered to the Dask workers once per map, not once per pass.

0ecdb0a scattered an NPZ map's row chunks instead of pickling them into the graph, but
every pass sent the whole map again: two ``query_many`` calls scattered it twice, one
call with ``refine`` twice, and ``query_many_lazy(...).to_zarr`` three times (the lazy
graph's copy and one per pass of ``to_zarr``, the workers holding two copies). The
scattered array is kept while the map's embeddings array lives, and reused.
"""

from __future__ import annotations

import gc
import time
import weakref

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
zarr = pytest.importorskip("zarr")

from _dask_table import WORDS, one_worker_client, table_quash  # noqa: E402
from _dask_table import words as _words  # noqa: E402

from quash_plugins.core.types import LatentMap  # noqa: E402
from quash_plugins.engine import dask_arrays  # noqa: E402
from quash_plugins.engine.dask_arrays import as_dask, scattered_array  # noqa: E402

TEXTS = ["chair", "sofa"]


@pytest.fixture(scope="module")
def client():
    yield from one_worker_client()


@pytest.fixture
def scatters(monkeypatch):
    """The calls of ``Client.scatter`` (each a list of the parts sent)."""
    calls: list[int] = []
    real = distributed.Client.scatter

    def counted(self, data, *args, **kwargs):
        calls.append(len(data) if isinstance(data, list) else 1)
        return real(self, data, *args, **kwargs)

    monkeypatch.setattr(distributed.Client, "scatter", counted)
    return calls


def _map(vecs, n: int = 3000, seed: int = 5) -> LatentMap:
    rng = np.random.default_rng(seed)
    labels = rng.integers(0, 3, size=n)
    emb = np.stack([vecs[WORDS[k]] for k in labels]) + 0.6 * rng.normal(size=(n, 32))
    emb[rng.random(n) < 0.01] = 0  # unobserved rows
    return LatentMap(emb.astype(np.float32))


def _quash(vecs, **kw):
    """Two passes a query (refine), several chunks each."""
    return table_quash(vecs, refine={}, **kw)


def test_two_query_many_calls_with_refine_scatter_the_map_once(client, scatters):
    vecs = _words(32)
    lmap = _map(vecs)
    expected = _quash(vecs).query_many(lmap, TEXTS)
    q = _quash(vecs, backend="dask", client=client)
    for _ in range(2):  # two passes each (refine), two calls
        got = q.query_many(lmap, TEXTS)
        for e, g in zip(expected, got, strict=True):
            assert 0 < e.n_matched < lmap.n  # a meaningful comparison
            np.testing.assert_array_equal(g.mask, e.mask)
            np.testing.assert_array_equal(g.scores, e.scores)
    assert len(scatters) == 1 and scatters[0] > 1, scatters  # one scatter of every chunk


def test_lazy_query_and_to_zarr_scatter_the_map_once(client, scatters, tmp_path):
    vecs = _words(32)
    lmap = _map(vecs, seed=6)
    expected = _quash(vecs).query_many(lmap, TEXTS)
    lazy = _quash(vecs, backend="dask", client=client).query_many_lazy(lmap, TEXTS)
    out = lazy.to_zarr(tmp_path / "result.zarr")
    assert len(scatters) == 1, scatters  # the lazy graph's chunks serve to_zarr's passes
    group = zarr.open_group(str(out), mode="r")
    for i, e in enumerate(expected):
        np.testing.assert_array_equal(group["masks"][i], e.mask)
        # not bit for bit at chunk_mb=0.05, with or without the scatter cache (~1e-6)
        np.testing.assert_allclose(group["scores"][i], e.scores, rtol=0, atol=1e-5)


def test_the_scattered_chunks_go_with_the_map(client, scatters):
    lmap = LatentMap(np.random.default_rng(0).normal(size=(1000, 8)).astype(np.float32))
    emb = lmap.embeddings
    x = as_dask(lmap, 300, client)
    held = {str(k) for keys in client.has_what().values() for k in keys}
    assert len(held) >= 4
    np.testing.assert_array_equal(as_dask(lmap, 250, client).compute(), emb)  # rechunked
    assert len(scatters) == 1 and id(emb) in dask_arrays._SCATTERED
    gone = weakref.ref(emb)
    key = id(emb)
    del lmap, emb, x
    gc.collect()
    assert gone() is None and key not in dask_arrays._SCATTERED
    deadline = time.monotonic() + 30
    while held & {str(k) for keys in client.has_what().values() for k in keys}:
        assert time.monotonic() < deadline, "the chunks stay on the workers"
        time.sleep(0.1)


def test_lost_chunks_or_a_closed_client_are_not_reused(client, scatters, monkeypatch):
    lmap = LatentMap(np.random.default_rng(1).normal(size=(900, 8)).astype(np.float32))
    emb = lmap.embeddings
    as_dask(lmap, 300, client)
    assert scattered_array(emb, client) is not None
    with monkeypatch.context() as m:
        m.setattr(client, "status", "closed")
        assert scattered_array(emb, client) is None
    # chunks lost (as with a worker that died): the next pass scatters the map again
    (_, _, futures) = dask_arrays._SCATTERED[id(emb)][1][str(client.id)]
    client.cancel(list(futures))
    deadline = time.monotonic() + 30
    while any(f.status == "finished" for f in futures):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert scattered_array(emb, client) is None
    np.testing.assert_array_equal(as_dask(lmap, 300, client).compute(), emb)
    assert len(scatters) == 2
