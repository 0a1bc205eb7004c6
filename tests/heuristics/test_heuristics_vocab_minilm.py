"""The vocabulary heuristic with the real MiniLM encoder (embeds 1,000+ names: slow)."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.core import registry
from quash_plugins.core.interfaces import ExpansionContext

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def minilm():
    pytest.importorskip("sentence_transformers")
    return registry.create("encoders", "minilm", device="cpu")


def test_armchair_is_a_positive_of_chair(minilm, monkeypatch, tmp_path):
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path))
    h = registry.create("heuristics", "vocabulary")
    qs = h.expand("chair", ExpansionContext(encoder=minilm, seed=0))
    assert "armchair" in qs.positives
    assert qs.positives[0] == "chair"
    # negatives are genuinely less similar than every positive
    E = minilm.encode_text(qs.positives + qs.negatives)
    sims = E @ E[0]
    n = len(qs.positives)
    assert sims[n:].max() < sims[1:n].min()
    assert not any(x.endswith("chair") for x in qs.negatives)
    assert len(qs.negatives) > 10
    # deterministic
    again = h.expand("chair", ExpansionContext(encoder=minilm, seed=7))
    assert again.positives == qs.positives and again.negatives == qs.negatives
    assert np.isfinite(sims).all()


def test_taxonomy_resolves_with_minilm(minilm):
    tax = {"chair": ["armchair", "stool"], "table": ["desk"], "toilet": ["urinal"]}
    h = registry.create("heuristics", "taxonomy", taxonomy=tax)
    qs = h.expand("office chair", ExpansionContext(encoder=minilm))
    assert qs.provenance["resolved"]["to"] == "chair"
