"""Many queries in one call: one encoder call for every query set, one expansion per query.

The issue's 1,000 queries took 396 s because each query set was encoded on its own (one
cache lookup, one encoder call and one cache write per query). The speed figure lives in
docs/benchmarks.md (benchmarks/bench_queries.py); here the call counts and the results.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

from quash_plugins import LatentMap, Quash, QuerySet, registry
from quash_plugins.core.interfaces import Heuristic
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine import training

WORDS = [f"word{i}" for i in range(60)] + ["other", "background", "nothing"]


class CountingTable(TableEncoder):
    """A table encoder that records every call into it."""

    def __init__(self, table):
        super().__init__(table=table)
        self.calls: list[list[str]] = []

    def encode_text(self, texts):
        self.calls.append(list(texts))
        return super().encode_text(texts)


class SharedNegatives(Heuristic):
    """Positives: the query and its neighbour; negatives: ten words shared by every query."""

    name = "shared-negatives"

    def __init__(self):
        self.calls: list[str] = []

    def expand(self, query, context=None):
        self.calls.append(query)
        i = int(query.removeprefix("word"))
        return QuerySet(query, [query, f"word{(i + 1) % 40}"], [f"word{k}" for k in range(40, 50)])


@pytest.fixture
def setup():
    rng = np.random.default_rng(0)
    strings = [*WORDS, *(f"{t} {w}" for t in ("a", "the") for w in WORDS)]
    table = {w: rng.normal(size=8).astype(np.float32) for w in strings}
    emb = rng.normal(size=(500, 8)).astype(np.float32)

    def build(**kw):
        enc = CountingTable(table)
        heur = SharedNegatives()
        q = Quash(enc, heur, registry.create("classifiers", "contrast"), instances=False, **kw)
        return q, enc, heur

    return build, LatentMap(emb)


def test_one_encoder_call_for_all_query_sets_and_one_expansion_per_query(setup):
    build, lmap = setup
    q, enc, heur = build()
    texts = [f"word{i}" for i in range(40)] + ["word3", "word7"]  # two repeated
    results = q.query_many(lmap, texts)
    # one call for the queries themselves, one for the rest of every query set
    assert len(enc.calls) == 2 and enc.calls[0] == list(dict.fromkeys(texts))
    embedded = [s for call in enc.calls for s in call]
    assert len(embedded) == len(set(embedded))  # each distinct string once
    assert set(embedded) == {f"word{i}" for i in range(50)} | {"other", "background", "nothing"}
    assert sorted(heur.calls) == sorted(set(texts))  # one heuristic call per query
    # the same answers as one query at a time: the same masks, and the same scores up to
    # float32 rounding (the fused GEMM is wider for 42 queries than for one, and BLAS
    # libraries may pick another kernel for another width: OpenBLAS 0.3.31 differs in
    # the last bit on 17 % of these scores)
    for text, r in zip(texts, results):
        single, _, _ = build()
        one = single.query(lmap, text)
        np.testing.assert_array_equal(r.mask, one.mask)
        np.testing.assert_allclose(r.scores, one.scores, rtol=1e-5, atol=1e-6)


def test_templates_and_the_per_call_bound(setup, monkeypatch):
    build, lmap = setup
    q, enc, _ = build(prompt_templates={"mode": "mean", "templates": ["a {}", "the {}"]})
    texts = [f"word{i}" for i in range(30)]
    batched = q.query_many(lmap, texts)
    assert len(enc.calls) == 2 and "the word40" in enc.calls[1]
    monkeypatch.setattr(training, "MAX_STRINGS_PER_CALL", 40)
    q2, enc2, _ = build(prompt_templates={"mode": "mean", "templates": ["a {}", "the {}"]})
    split = q2.query_many(lmap, texts)
    assert len(enc2.calls) > 1 and max(len(c) for c in enc2.calls) <= 40
    for a, b in zip(batched, split):
        np.testing.assert_array_equal(a.scores, b.scores)


class EmbedsItsQuery(SharedNegatives):
    """A heuristic that embeds its query, as ``vocabulary`` does."""

    def expand(self, query, context=None):
        from quash_plugins.core.text import encode_texts

        encode_texts(context.encoder, [query], context.extra.get("cache"))
        return super().expand(query, context)


@pytest.mark.parametrize("cache", [False, True])
def test_heuristics_that_embed_their_query_make_no_call_per_query(setup, tmp_path, cache):
    from quash_plugins.engine import TextEmbeddingCache

    build, lmap = setup
    q, enc, _ = build(cache=TextEmbeddingCache(tmp_path / "c") if cache else None)
    q.heuristic = EmbedsItsQuery()
    q.query_many(lmap, [f"word{i}" for i in range(30)])
    assert len(enc.calls) == 2


def test_many_queries_show_progress(setup, caplog, monkeypatch):
    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    build, lmap = setup
    q, _, _ = build()
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    q.query_many(lmap, [f"word{i}" for i in range(25)])
    text = caplog.text
    assert "expanding 25 queries: 25/25" in text and "fitting 25 classifiers: 25/25" in text
    assert "encoding 25 query sets" in text
    caplog.clear()
    q.query_many(lmap, ["word1", "word2"])
    assert "expanding" not in caplog.text  # a handful of queries stays quiet
