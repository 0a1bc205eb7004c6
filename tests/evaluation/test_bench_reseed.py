"""benchmarks/bench_reseed.py: the queries it times and the two configs it compares."""

from __future__ import annotations

import pytest
import yaml
from _bench import load_bench


@pytest.fixture(scope="module")
def bench():
    return load_bench("bench_reseed")


def test_closed_queries_are_the_present_labels_then_the_absent_ones(bench, tmp_path):
    stem = tmp_path / "scene"
    (tmp_path / "scene.queries.yaml").write_text(yaml.safe_dump({"present": ["sofa", "bed"]}))
    tax = {"bed": ["cot"], "piano": [], "sofa": ["couch"], "bathtub": ["tub"]}
    (tmp_path / "scene.taxonomy.yaml").write_text(yaml.safe_dump(tax, sort_keys=False))
    assert bench.closed_queries(stem) == ["sofa", "bed", "piano", "bathtub"]


@pytest.mark.parametrize("reseed", [False, True])
def test_the_two_configs_differ_only_in_reseed(bench, tmp_path, reseed):
    tax = tmp_path / "scene.taxonomy.yaml"
    tax.write_text(yaml.safe_dump({"bed": ["cot"], "sofa": []}))
    q = bench.quash(tax, reseed)
    assert q.presence.reseed is reseed
    other = bench.quash(tax, not reseed)
    assert vars(q.presence) == {**vars(other.presence), "reseed": reseed}
    assert q.refine == other.refine
