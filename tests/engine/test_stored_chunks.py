"""A zarr store whose own chunks are read many times over by the pass is warned about,
and the scores stay those of the same map in memory."""

from __future__ import annotations

import logging

import numpy as np
import pytest

zarr = pytest.importorskip("zarr")

from quash_plugins import registry  # noqa: E402
from quash_plugins.adapters import read_map  # noqa: E402
from quash_plugins.adapters._zarr_store import write_zarr_map  # noqa: E402
from quash_plugins.core.once import forget  # noqa: E402
from quash_plugins.core.types import LatentMap  # noqa: E402
from quash_plugins.engine.classify import classify_local  # noqa: E402
from quash_plugins.engine.stored_chunks import decodes_per_chunk  # noqa: E402

N, D = 600, 16


def _emb() -> np.ndarray:
    return np.random.default_rng(3).normal(size=(N, D)).astype(np.float16)


def _clf():
    x = np.random.default_rng(4).normal(size=(6, D)).astype(np.float32)
    return registry.create("classifiers", "contrast").fit(x, np.array([1, 1, 1, 0, 0, 0]))


def test_decodes_per_chunk_counts_reads() -> None:
    # brute force: each read of rows [a, b) decodes every stored chunk it touches
    for n, rows, stored in [(600, 64, 100), (600, 100, 64), (1000, 250, 250), (7, 3, 5)]:
        touched = sum(
            len({r // stored for r in range(a, min(n, a + rows))}) for a in range(0, n, rows)
        )
        assert decodes_per_chunk(n, rows, stored) == touched / -(-n // stored)


def test_odd_chunks_warn_once_and_score_as_in_memory(tmp_path, caplog) -> None:
    forget("stored-chunks")
    path = tmp_path / "odd.zarr"
    g = zarr.open_group(str(path), mode="w")
    g.create_array("embeddings", data=_emb(), chunks=(N, 4))  # one row of column chunks
    lmap = read_map(path)
    clf = _clf()
    budget = 64 * 4 * D  # reads of 64 rows
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.stored_chunks"):
        scores, observed = classify_local(lmap, [clf], chunk_bytes=budget)
        classify_local(lmap, [clf], chunk_bytes=budget)
    warned = [r.getMessage() for r in caplog.records if "stored in chunks" in r.getMessage()]
    assert len(warned) == 1, warned
    assert f"chunks of {N} rows x 4 columns" in warned[0]
    assert f"quash convert {path} NEW.zarr" in warned[0]
    expected, _ = classify_local(LatentMap(_emb()), [clf], chunk_bytes=budget)
    np.testing.assert_array_equal(scores[0], expected[0])


def test_convert_store_read_in_larger_chunks_is_quiet(tmp_path, caplog) -> None:
    forget("stored-chunks")
    path = write_zarr_map(LatentMap(_emb()), tmp_path / "m.zarr", chunk_mb=100 * D * 2 / 2**20)
    lmap = read_map(path)
    assert lmap.embeddings.chunks == (100, D)
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.stored_chunks"):
        classify_local(lmap, [_clf()], chunk_bytes=400 * 4 * D)  # 4 stored chunks a read
    assert not [r for r in caplog.records if "stored in chunks" in r.getMessage()]
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.stored_chunks"):
        classify_local(lmap, [_clf()], chunk_bytes=30 * 4 * D)  # a chunk read ~4 times
    (msg,) = [r.getMessage() for r in caplog.records if "stored in chunks" in r.getMessage()]
    assert "raise chunk_mb" in msg and "quash convert" not in msg  # convert's own chunks


def test_a_tiny_chunk_mb_is_warned_about_once_with_the_same_scores(caplog) -> None:
    """chunk_mb so small that the pass runs hundreds of chunks of a few rows (a typo such
    as 1e-6 runs for hours on a real map) is warned about once, naming the rows."""
    forget("small-chunks")
    emb = _emb().astype(np.float32)
    lmap = LatentMap(emb)
    clf = _clf()
    ref, _ = classify_local(lmap, [clf])
    tiny = 2 * 4 * D  # bytes: two rows per chunk
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.stored_chunks"):
        got, _ = classify_local(lmap, [clf], chunk_bytes=tiny)
        classify_local(lmap, [clf], chunk_bytes=tiny)
    from quash_plugins.engine.classify import extra_bytes_per_row

    rows = lmap.chunk_rows(tiny, extra_bytes_per_row([clf]))
    assert rows < 256
    said = [r.getMessage() for r in caplog.records if "chunk_mb gives chunks of" in r.getMessage()]
    assert len(said) == 1 and f"only {rows} rows" in said[0]
    assert f"chunks of {tiny:,} bytes" in said[0]  # as given, not a rounded chunk_mb
    assert f"{-(-N // rows)} chunks" in said[0]
    np.testing.assert_allclose(got[0], ref[0], rtol=1e-5, atol=1e-6)
    # chunks of a few hundred rows, or few chunks: no warning
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="quash_plugins.engine.stored_chunks"):
        classify_local(lmap, [clf], chunk_bytes=300 * 2**10)
        classify_local(LatentMap(emb[:100]), [clf], chunk_bytes=tiny)
    assert not [r for r in caplog.records if "chunk_mb gives chunks of" in r.getMessage()]
