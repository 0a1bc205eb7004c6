"""The evaluation tab of a recording: its plots' titles, read back from the .rrd."""

from __future__ import annotations

import pytest
import rerun as rr
from rerun.chunk import RrdReader

from quash_plugins.viewer import RerunLogger


@pytest.fixture(autouse=True)
def _strict():
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def _views(reader: RrdReader) -> dict[str, str]:
    """{origin: display name} of the stored blueprint's views."""
    out = {}
    for store in reader.blueprints():
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            if "ViewBlueprint:space_origin" in rb.schema.names:
                origins = rb.column("ViewBlueprint:space_origin").to_pylist()
                names = rb.column("ViewBlueprint:display_name").to_pylist()
                out |= {o[0]: n[0] for o, n in zip(origins, names) if o and n}
    return out


def _log_report(path, configs, queries, absent=()):
    rec = rr.RecordingStream("quash-eval-test")
    rec.save(path)
    logger = RerunLogger(rec)
    logger.log_evaluation(configs, queries, "| method |\n|---|\n| one |", absent=absent)
    logger.close()
    rec.disconnect()
    return RrdReader(path)


def test_each_plot_names_its_metric_as_the_tables_do_and_what_absence_counts(tmp_path):
    """The plots were titled with the metric's entity name ('f1 per query', 'ap per
    query', 'absence per query': 1 of what?); they now read as the tables' columns and
    the absence plot says what 1 and 0 mean."""
    row = {"f1": 0.5, "precision": 0.4, "recall": 0.7, "iou": 0.3, "ap": 0.6}
    configs = [
        {
            "name": "one",
            "per_query": {"chair": row},
            "absence": {"per_query": {"piano": {"matched": 0, "empty": True}}},
        }
    ]
    views = _views(_log_report(tmp_path / "e.rrd", configs, ["chair"], absent=["piano"]))
    titles = {o.removeprefix("eval/"): n for o, n in views.items() if o.startswith("eval/")}
    assert set(titles) == {*row, "absence"}
    assert titles["f1"] == "F1 per query"
    assert titles["iou"] == "IoU per query"
    assert titles["ap"] == "AP per query"
    assert titles["precision"] == "precision per query"
    assert "1 = answered with nothing" in titles["absence"]
    assert "0 = matched something" in titles["absence"]


def test_a_metric_of_its_own_keeps_its_name(tmp_path):
    rec = rr.RecordingStream("quash-eval-test")
    out = tmp_path / "e.rrd"
    rec.save(out)
    logger = RerunLogger(rec)
    logger.log_eval_scalars("one", {"n_pred": 0.5}, "chair")
    logger.close()
    rec.disconnect()
    assert _views(RrdReader(out))["eval/n_pred"] == "n_pred per query"
