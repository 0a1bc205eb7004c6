"""Progress lines without a terminal: every ~10 %, at most one per MIN_INTERVAL seconds."""

from __future__ import annotations

import logging

import pytest

import quash_plugins.core.progress as prog


@pytest.fixture
def clock(monkeypatch):
    now = [100.0]
    monkeypatch.setattr(prog.time, "perf_counter", lambda: now[0])
    monkeypatch.setattr(prog.sys.stderr, "isatty", lambda: False, raising=False)
    monkeypatch.setattr(prog, "QUIET", False)
    return now


def _lines(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "quash_plugins.progress"]


def test_quick_work_logs_nothing(clock, caplog):
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    with prog.progress(40, "expanding 40 queries") as advance:
        for _ in range(40):
            clock[0] += 0.01  # 0.4 s in all
            advance(1)
    assert _lines(caplog) == []


def test_slow_work_logs_each_tenth_at_most_every_interval_and_its_end(clock, caplog):
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    with prog.progress(100, "encoding") as advance:
        for i in range(100):
            clock[0] += 0.5 if i < 50 else 0.05  # slow, then fast
            advance(1)
    lines = _lines(caplog)
    done = [int(line.split(": ")[1].split("/")[0]) for line in lines]
    # slow half: every 10 % step is 5 s apart, so each is logged; fast half: the steps
    # come 0.5 s apart, so only one line per 2 s, and the closing line
    assert done[:5] == [10, 20, 30, 40, 50]
    assert done[-1] == 100 and lines[-1].startswith("encoding: 100/100 (100%")
    assert len(done) < 10
    assert done == sorted(done)


def test_the_interval_is_a_setting(clock, caplog, monkeypatch):
    monkeypatch.setattr(prog, "MIN_INTERVAL", 0.0)
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    with prog.progress(20, "fitting") as advance:
        for _ in range(20):
            advance(1)
    assert len(_lines(caplog)) == 10


def test_times_count_from_the_start_mark(clock, caplog):
    """advance(0) before any counted work marks its start: 20 s of text side before the
    map pass are not reported as classification time."""
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    with prog.progress(10, "classifying 10 items") as advance:
        clock[0] += 20.0  # expand, encode, fit: not counted
        advance(0)
        for _ in range(10):
            clock[0] += 0.5
            advance(1)
    lines = _lines(caplog)
    assert lines[-1] == "classifying 10 items: 10/10 (100%, 5.0s)"
    # without the mark the clock runs from the `with`
    caplog.clear()
    with prog.progress(10, "classifying 10 items") as advance:
        clock[0] += 20.0
        for _ in range(10):
            clock[0] += 0.5
            advance(1)
    assert _lines(caplog)[-1] == "classifying 10 items: 10/10 (100%, 25.0s)"
    # a zero advance after counted work is no mark
    caplog.clear()
    with prog.progress(4, "x") as advance:
        for _ in range(4):
            clock[0] += 1.0
            advance(1)
            advance(0)
    assert _lines(caplog)[-1] == "x: 4/4 (100%, 4.0s)"
