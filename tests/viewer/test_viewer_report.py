"""RerunLogger.log_report and ``quash eval --rrd``: an evaluation's map and every method's
results, coloured by outcome, read back from the .rrd and checked against TP, FP and FN
computed here from the masks and the map's labels."""

from __future__ import annotations

import json

import numpy as np
import pytest
import rerun as rr
from _viewer_maps import make_quash, voxel_map, write_table_config
from test_viewer_rrd import blueprint_contents, read_rrd, rows, view_names

from quash_plugins.core.errors import QuashError
from quash_plugins.evaluation.report import evaluate
from quash_plugins.viewer import MATCH_COLOR, RerunLogger

#: What the colours mean, spelled here rather than read from the package.
BLUE, VERMILLION, YELLOW = (0, 114, 178), (213, 94, 0), (240, 228, 66)


@pytest.fixture(autouse=True)
def _strict():
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def mislabelled_map():
    """The voxel map with labels that disagree with its embeddings: three chair items
    labelled floor (a chair query matches them: false positives), four floor items
    labelled chair (missed: false negatives), one chair item unlabelled (matched, not
    scored)."""
    lmap = voxel_map()
    labels = lmap.labels.copy()
    chair, floor = np.flatnonzero(labels == 0), np.flatnonzero(labels == 2)
    labels[chair[:3]] = 2
    labels[floor[:4]] = 0
    labels[chair[3]] = -1
    lmap.labels = labels
    return lmap


def _rgb(packed: list[int]) -> list[tuple[int, int, int]]:
    return [((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in packed]


def _by_colour(by_path, entity: str, step: int) -> dict[tuple, set[tuple]]:
    """{colour: positions drawn in it} of ``entity`` at ``step``."""
    [centers] = [v for t, v in rows(by_path[entity], "Boxes3D:centers") if t == step]
    [colors] = [v for t, v in rows(by_path[entity], "Boxes3D:colors") if t == step]
    if len(colors) == 1:
        colors = colors * len(centers)
    out: dict[tuple, set[tuple]] = {}
    for p, c in zip(_keys(centers), _rgb(colors)):
        out.setdefault(c, set()).add(p)
    return out


def _keys(points) -> list[tuple]:
    return [tuple(float(x) for x in p) for p in np.asarray(points, np.float32).round(4)]


def _positions(lmap, sel: np.ndarray) -> set[tuple]:
    return set(_keys(np.asarray(lmap.positions)[sel]))


def _expected(lmap, mask, label: str | None, exclude=()) -> dict[str, np.ndarray]:
    """TP, FP, FN and matched-but-unscored items, from the mask and the map's labels."""
    labels = np.asarray(lmap.labels)
    names = list(lmap.label_names)
    gone = {e.casefold() for e in exclude}
    counted = (labels >= 0) & ~np.isin(
        labels, [i for i, n in enumerate(names) if n.casefold() in gone]
    )
    truth = np.isin(labels, [i for i, n in enumerate(names) if n == label])
    mask = np.asarray(mask, bool)
    return {
        "tp": mask & truth & counted,
        "fp": mask & ~truth & counted,
        "fn": ~mask & truth & counted,
        "unscored": mask & ~counted,
    }


def _check_step(by_path, lmap, entity, step, exp):
    drawn = _by_colour(by_path, entity, step)
    want = {
        BLUE: _positions(lmap, exp["tp"]),
        VERMILLION: _positions(lmap, exp["fp"]),
        YELLOW: _positions(lmap, exp["fn"]),
        tuple(MATCH_COLOR): _positions(lmap, exp["unscored"]),
    }
    assert drawn == {c: p for c, p in want.items() if p}


def test_log_report_colours_every_result_by_outcome(tmp_path):
    lmap = mislabelled_map()
    report = evaluate(
        lmap,
        [make_quash()],
        queries=["chair", "sofa"],
        absent=["nothing", "other"],
        keep_results=True,
    )
    [config] = report.configs
    results = report.results[config["name"]]
    out = tmp_path / "r.rrd"
    rec = rr.RecordingStream("quash-eval")
    rec.save(out)
    with RerunLogger(rec) as logger:
        logger.log_report(lmap, report)
    rec.disconnect()
    reader, by_path = read_rrd(out)
    exclude = report.provenance["exclude"]
    docs = {t: str(v[0]) for t, v in rows(by_path["queries/quash"], "TextDocument:text")}
    seen = {"fp": 0, "fn": 0, "unscored": 0}
    for step, (q, r) in enumerate(zip([*report.queries, *report.absent], results)):
        label = q if q in report.queries else None
        exp = _expected(lmap, r.mask, label, exclude)
        _check_step(by_path, lmap, "world/matches/quash", step, exp)
        n = {k: int(v.sum()) for k, v in exp.items()}
        seen = {k: seen[k] + n[k] for k in seen}
        if label:  # the report counts alike
            m = config["per_query"][q]
            assert (m["tp"], m["fp"], m["fn"]) == (n["tp"], n["fp"], n["fn"])
            assert f"Colours against the label {q}:" in docs[step]
        else:  # an absence query: every counted match is a false positive
            assert n["tp"] == n["fn"] == 0
            assert config["absence"]["per_query"][q]["matched"] == n["fp"]
            assert "Colours against no label of the map (an absence query)" in docs[step]
        assert f"**blue**: true positives (matched, of the label) {n['tp']:,}" in docs[step]
        assert (
            f"**vermillion**: false positives (matched, not of the label) {n['fp']:,}"
            in (docs[step])
        )
        assert f"**yellow**: false negatives (of the label, not matched) {n['fn']:,}" in docs[step]
    assert all(seen.values()), seen  # the map gave every outcome somewhere
    # the evaluation is there too, and the viewer opens on the method
    assert rows(by_path["eval/f1/quash"], "Scalars:scalars")
    assert "quash: map and matches" in view_names(reader)
    assert "+ world/matches/quash" in blueprint_contents(reader)


def test_without_ground_truth_the_matches_stay_magenta(tmp_path):
    """log_result without truth (quash query): every drawn item is a match, magenta."""
    lmap = mislabelled_map()
    results = make_quash().query_many(lmap, ["chair", "sofa"])
    out = tmp_path / "q.rrd"
    rec = rr.RecordingStream("quash-query")
    rec.save(out)
    with RerunLogger(rec) as logger:
        for i, r in enumerate(results):
            logger.log_result(lmap, r, index=i)
    rec.disconnect()
    _, by_path = read_rrd(out)
    for step, r in enumerate(results):
        assert _by_colour(by_path, "world/matches/quash", step) == {
            tuple(MATCH_COLOR): _positions(lmap, r.mask)
        }
    docs = [str(v[0]) for _, v in rows(by_path["queries/quash"], "TextDocument:text")]
    assert docs and not any("Colours against" in d for d in docs)


def test_log_report_needs_the_results(tmp_path):
    lmap = mislabelled_map()
    report = evaluate(lmap, [make_quash()], queries=["chair"])
    rec = rr.RecordingStream("quash-eval")
    logger = RerunLogger(rec)
    with pytest.raises(QuashError, match="keep_results=True"):
        logger.log_report(lmap, report)
    assert not logger._listed and logger._map_key is None  # nothing logged


def test_log_result_refuses_ground_truth_of_another_length(tmp_path):
    lmap = mislabelled_map()
    [r] = make_quash().query_many(lmap, ["chair"])
    logger = RerunLogger(rr.RecordingStream("quash-eval"))
    with pytest.raises(QuashError, match="truth"):
        logger.log_result(lmap, r, index=0, truth=np.zeros(lmap.n - 1, bool))


def test_the_viewer_and_the_evaluation_match_label_names_with_one_rule():
    from quash_plugins.core.text import label_key
    from quash_plugins.evaluation import queries
    from quash_plugins.viewer import _rerun

    assert queries.label_key is label_key and _rerun.label_key is label_key
    for name, key in (("TV_Monitor", "tv monitor"), ("  Void ", "void"), ("ß", "ss")):
        assert label_key(name) == key


def test_cli_eval_rrd_logs_the_map_and_each_methods_results(tmp_path, monkeypatch):
    """``quash eval --rrd``: the map, a tab per method with its results coloured by outcome
    (TP, FP and FN those of the JSON report, counted here from the masks), the plots; and
    the results are kept only for the viewer."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main
    from quash_plugins.evaluation import report as report_module

    lmap = mislabelled_map()
    map_path = write_npz_map(lmap, tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    kept, masks = [], {}
    real = report_module.evaluate

    def spy(*args, **kwargs):
        kept.append(kwargs.get("keep_results", False))
        rep = real(*args, **kwargs)
        masks.update({n: [r.mask for r in rs] for n, rs in rep.results.items()})
        return rep

    monkeypatch.setattr(report_module, "evaluate", spy)
    out, js = tmp_path / "e.rrd", tmp_path / "e.json"
    args = ["-q", "eval", str(map_path), "-c", str(cfg), "--queries", "chair,sofa"]
    args += ["--absent", "other", "--exclude", "Floor", "--json", str(js)]
    assert main([*args, "--rrd", str(out)]) == 0
    assert main([*args[:-2], "--json", str(tmp_path / "plain.json")]) == 0
    assert kept == [True, False]
    [config] = json.loads(js.read_text())["configs"]
    reader, by_path = read_rrd(out)
    assert "world/map" in by_path
    assert "table-contrast: map and matches" in view_names(reader)
    for step, q in enumerate(["chair", "sofa", "other"]):
        label = q if q != "other" else None
        exp = _expected(lmap, masks["table-contrast"][step], label, exclude=["Floor"])
        _check_step(by_path, lmap, "world/matches/table_contrast", step, exp)
        if label:
            m = config["per_query"][q]
            assert (m["tp"], m["fp"], m["fn"]) == tuple(
                int(exp[k].sum()) for k in ("tp", "fp", "fn")
            )
    # with floor excluded, the chair items labelled floor are matched but not scored
    chair = _expected(lmap, masks["table-contrast"][0], "chair", exclude=["Floor"])
    assert chair["unscored"].sum() >= 3 and chair["fn"].sum() == 4


def test_cli_eval_logs_the_map_before_the_configs_run(tmp_path, monkeypatch):
    """quash eval --serve-web prints its URL before the evaluation: the map is logged
    then too, so a viewer opened meanwhile shows it."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.cli.main import main
    from quash_plugins.evaluation import report as report_module
    from quash_plugins.viewer._log_map import MapLogging

    map_path = write_npz_map(mislabelled_map(), tmp_path / "map.npz")
    logged: list[str] = []
    real_log_map = MapLogging.log_map

    def log_map(self, lmap):
        logged.append(f"map {lmap.n}")
        return real_log_map(self, lmap)

    def evaluate(*args, **kwargs):
        logged.append("evaluate")
        raise KeyboardInterrupt  # the rest of the command is not this test's

    monkeypatch.setattr(MapLogging, "log_map", log_map)
    monkeypatch.setattr(report_module, "evaluate", evaluate)
    cfg = write_table_config(tmp_path)
    code = main(["-q", "eval", str(map_path), "-c", str(cfg), "--rrd", str(tmp_path / "e.rrd")])
    assert code == 130  # interrupted, as Ctrl-C is
    assert logged[:2] == [f"map {mislabelled_map().n}", "evaluate"]
