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


def _docs(path) -> dict[tuple[str, int], str]:
    """{(entity, step): text} of every text document logged at a query step."""
    out = {}
    for chunk in RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        if "TextDocument:text" in rb.schema.names and "query" in rb.schema.names:
            for t, v in zip(
                rb.column("query").to_pylist(), rb.column("TextDocument:text").to_pylist()
            ):
                if v:
                    out[(chunk.entity_path.lstrip("/"), t)] = v[0]
    return out


def test_each_query_step_says_its_scores_tp_fp_fn_and_an_absence_querys_answer(tmp_path):
    """The tab of a method showed what it matched but not how well: its scores were only
    in the evaluation tab's plots. Each step now has the method's scores in words, with
    TP, FP and FN (or, for an absence query, how many items it matched), read from the
    report, beside the query set."""
    from _viewer_maps import make_quash, voxel_map

    from quash_plugins.evaluation import evaluate

    lmap = voxel_map()
    quash = make_quash()
    rep = evaluate(lmap, [quash], queries=["chair", "sofa"], absent=["nothing"], keep_results=True)
    [report] = rep.configs
    out = tmp_path / "e.rrd"
    rec = rr.RecordingStream("quash-eval-test")
    rec.save(out)
    logger = RerunLogger(rec)
    for i, r in enumerate(rep.results[report["name"]]):
        logger.log_result(lmap, r, index=i)
    logger.log_evaluation(rep.configs, rep.queries, rep.to_markdown(), absent=rep.absent)
    logger.close()
    rec.disconnect()
    docs = _docs(out)
    c = "quash"
    for i, q in enumerate(["chair", "sofa"]):
        row = report["per_query"][q]
        text = docs[(f"query_scores/{c}", i)]
        assert text.startswith(
            f'**{report["name"]}** on "{q}" (ground truth: label `{row["label"]}`)'
        )
        assert f"F1 {row['f1']:.3f}" in text and f"AP {row['ap']:.3f}" in text
        assert f"TP {row['tp']} · FP {row['fp']} · FN {row['fn']}" in text
        assert f"{row['tp'] + row['fp']} items matched" in text
        # the same numbers as the mask logged at that step
        assert row["tp"] + row["fp"] == rep.results[report["name"]][i].n_matched
    absent = report["absence"]["per_query"]["nothing"]
    text = docs[(f"query_scores/{c}", 2)]
    assert "(absence query)" in text and f"Matched {absent['matched']} items" in text
    assert ("empty, as it should be" in text) == absent["empty"]
    # shown in the method's tab, above its query set
    views = _views(RrdReader(out))
    assert views[f"query_scores/{c}"] == f"{report['name']}: this query's scores"
