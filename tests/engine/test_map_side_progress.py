"""Progress of the map side: the refits and presence checks counted query by query, and
each config's map passes in ``evaluate`` counted in items.

Measured (demo:quash-labels, 69 queries, a 51,000-voxel scene, 2 cores): the two shared
map passes took 18 s and 23 s, the refits 7 s, the presence checks 11 s, all without a
line of progress.
"""

from __future__ import annotations

import logging

import pytest
from test_presence import TAX, _encoder, _object_map

import quash_plugins.core.progress as prog
from quash_plugins import Quash
from quash_plugins.evaluation import evaluate
from quash_plugins.heuristics import TaxonomyHeuristic

QUERIES = ["bed", "chair", "sofa", "cot", "futon"]


@pytest.fixture
def logged(monkeypatch, caplog):
    """Progress as log lines (no terminal), every step logged; the lines it gave."""
    monkeypatch.setattr(prog.sys.stderr, "isatty", lambda: False, raising=False)
    monkeypatch.setattr(prog, "QUIET", False)
    monkeypatch.setattr(prog, "MIN_INTERVAL", 0.0)
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")

    def lines(prefix: str) -> list[str]:
        return [
            r.getMessage()
            for r in caplog.records
            if r.name == "quash_plugins.progress" and r.getMessage().startswith(prefix)
        ]

    return lines


def _quash(**kw):
    opts = {"refine": {}, "presence": {}, "instances": False, "name": "checked", **kw}
    return Quash(_encoder(), TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"), **opts)


def _counts(lines: list[str]) -> list[int]:
    return [int(line.split(": ")[-1].split("/")[0]) for line in lines]


def test_refits_and_presence_checks_are_counted_per_query(logged, monkeypatch):
    m = _object_map()
    quiet = _quash().query_many(m, QUERIES)  # under PROGRESS_QUERIES: no line
    assert logged("checked: refitting") == [] and logged("checked: presence") == []
    monkeypatch.setattr("quash_plugins.engine.pipeline.PROGRESS_QUERIES", 5)
    shown = _quash().query_many(m, QUERIES)
    refits = logged("checked: refitting 5 queries: ")
    checks = logged("checked: presence check of 5 queries: ")
    # one line a query (5 queries: every 10 % step is one query), the last the total
    assert _counts(refits) == [1, 2, 3, 4, 5]
    assert _counts(checks) == [1, 2, 3, 4, 5]
    assert refits[-1].startswith("checked: refitting 5 queries: 5/5 (100%")
    # counting changes no answer
    for a, b in zip(quiet, shown):
        assert (a.mask == b.mask).all() and (a.scores == b.scores).all()
        assert a.queryset.provenance == b.queryset.provenance


def test_evaluate_counts_each_configs_map_passes_in_items(logged):
    m = _object_map()  # 57 items: one block, so one step a pass
    report = evaluate(m, [_quash()], queries=["bed"], absent=["chair"])
    lines = logged("checked: 2 queries, 2 passes over 57 items: ")
    assert _counts(lines) == [57, 114]
    assert lines[-1].startswith("checked: 2 queries, 2 passes over 57 items: 114/114 (100%")
    one = evaluate(m, [_quash(refine=None, presence=None)], queries=["bed"])
    assert _counts(logged("checked: 1 query, 1 pass over 57 items: ")) == [57]
    assert report.configs[0]["name"] == "checked" and one.configs[0]["per_query"]["bed"]


def test_quiet_logs_no_map_side_progress(logged, monkeypatch):
    monkeypatch.setattr(prog, "QUIET", True)
    monkeypatch.setattr("quash_plugins.engine.pipeline.PROGRESS_QUERIES", 1)
    evaluate(_object_map(), [_quash()], queries=["bed"], absent=["chair"])
    assert logged("checked") == []
