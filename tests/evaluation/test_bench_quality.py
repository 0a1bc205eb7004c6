"""benchmarks/bench_quality.py: the fair protocol's configs and the targets' verdict.

The full benchmark takes most of an hour (docs/benchmarks.md); here its pieces: every
label-list method is given the same taxonomy file, the open-none scenario gives no one a
label list, and the verdict compares QuASH with the best *fair* peer of each scenario.
"""

from __future__ import annotations

import hashlib
import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def bq():
    spec = importlib.util.spec_from_file_location(
        "bench_quality", ROOT / "benchmarks" / "bench_quality.py"
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_label_list_methods_get_the_same_list_and_open_none_gets_none(bq, tmp_path):
    tax = tmp_path / "scene.taxonomy.yaml"
    closed = {c["name"]: c for c in bq.configs("closed", tax)}
    assert {"vlmaps-labels", "openscene-labels", "quash-labels"} <= set(closed)
    assert list(closed)[:3] == ["vlmaps", "conceptfusion", "lerf"]  # the peers come first
    files = {
        name: c["heuristic"].get("file")
        for name, c in closed.items()
        if isinstance(c.get("heuristic"), dict)
        and c["heuristic"]["name"] in ("taxonomy", "label-list", "auto")
    }
    # a method given a label list either names the scene's taxonomy or takes the map's
    # label names with that same file beside the map: never another list
    assert all(f in (None, str(tax)) for f in files.values()), files
    none = {c["name"]: c for c in bq.configs("open-none", tax)}
    assert set(none) == {"vlmaps", "conceptfusion", "lerf", "quash-vocabulary"}
    for c in none.values():
        h = c.get("heuristic")
        name = h["name"] if isinstance(h, dict) else h
        assert name not in ("taxonomy", "label-list", "auto"), c["name"]


def _rec(seed, scenario, f1s, recall=0.8, absence=1.0, given="x"):
    return {
        "generator": "g",
        "seed": seed,
        "scenario": scenario,
        "configs": [
            {
                "name": name,
                "given": given,
                "mean": {"f1": f1, "precision": f1, "recall": recall, "ap": 0.5, "inv_rank": 1.0},
                "per_query": {"a": {}, "b": {}},
                "absence": {"score": absence, "present_empty": 0, "per_query": {"z": {}}},
            }
            for name, f1 in f1s.items()
        ],
    }


def test_the_verdict_takes_the_best_fair_peer_and_every_target(bq):
    # the query-alone rules do not count as fair peers of the closed scenario
    f1 = {"conceptfusion": 0.9, "vlmaps-labels": 0.5, "openscene-labels": 0.6, "quash-labels": 0.72}
    recs = [_rec(0, "closed", f1), _rec(1, "closed", f1)]
    rows = bq.verdict(bq.summarise(recs))[2:]
    assert len(rows) == 1
    cells = [c.strip() for c in rows[0].strip("|").split("|")]
    assert cells[4] == "openscene-labels (0.600)" and cells[5] == "1.20x"
    assert cells[-1] == "yes"
    # recall under the floor, or one absent object matched, fails the target
    low = bq.verdict(bq.summarise([_rec(0, "closed", f1, recall=0.6)]))[2]
    leaky = bq.verdict(bq.summarise([_rec(0, "closed", f1, absence=0.5)]))[2]
    assert low.rstrip(" |").endswith("NO") and leaky.rstrip(" |").endswith("NO")
    # with no label list, the peers are the query-alone rules and the target is 2x
    none = {"conceptfusion": 0.3, "lerf": 0.2, "quash-vocabulary": 0.5}
    row = bq.verdict(bq.summarise([_rec(0, "open-none", none)]))[2]
    assert "conceptfusion (0.300)" in row and "1.67x" in row and row.rstrip(" |").endswith("NO")


def test_the_summary_names_the_scene_file_not_one_seeds(bq):
    # each seed's run names its own taxonomy file; a table over seeds names neither
    f1 = {"vlmaps-labels": 0.5, "quash-labels": 0.7}
    recs = [
        _rec(s, "closed", f1, given=f"the map's label names + hard-seed{s}.taxonomy.yaml")
        for s in (3, 14)
    ]
    methods = bq.summarise(recs)[("g", "closed")]
    assert methods["quash-labels"]["given"] == "the map's label names + SCENE.taxonomy.yaml"
    table = "\n".join(bq.table(methods))
    assert "seed3" not in table and "seed14" not in table
    assert bq.given_text("the query alone") == "the query alone"


def test_bench_unlisted_gives_every_method_the_map_names_alone(monkeypatch):
    from quash_plugins.core import registry
    from quash_plugins.core.errors import HeuristicError
    from quash_plugins.core.interfaces import ExpansionContext

    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    spec = importlib.util.spec_from_file_location(
        "bench_unlisted", ROOT / "benchmarks" / "bench_unlisted.py"
    )
    bu = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bu)
    cfgs = {c["name"]: c for c in bu.configs(["bed", "stove"])}
    assert list(cfgs) == list(bu.METHODS)
    for name, c in cfgs.items():
        h = dict(c["heuristic"])
        # the same list for everyone, in memory: no taxonomy file, none read beside the map
        assert "file" not in h and h["taxonomy"] == {"bed": [], "stove": []}, name
        assert ("unlisted" in h) == name.endswith("(unlisted: vocabulary)")
        heuristic = registry.create("heuristics", h.pop("name"), **h)
        if "unlisted" not in h:  # as shipped: only an encoder could resolve it
            with pytest.raises(HeuristicError, match="no encoder"):
                heuristic.expand("fireplace", ExpansionContext())
            continue
        # the opt-in rule keeps an object missing from the list its own concept
        qs = heuristic.expand("fireplace", ExpansionContext())
        assert qs.provenance["resolved"]["how"] == "unlisted" and "stove" in qs.negatives


def test_classes_file_runs_table_a_generators_on_it(bq, tmp_path, monkeypatch):
    import yaml

    from quash_plugins.demo.class_file import class_table_data
    from quash_plugins.demo.scene import class_set

    monkeypatch.setattr(bq, "GENERATORS", dict(bq.GENERATORS))
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(class_table_data(class_set("a")), sort_keys=False))
    names = bq.with_classes(["low-noise", "hard"], path)
    assert names == ["mine-low-noise", "mine-hard"]
    assert bq.GENERATORS["mine-low-noise"] == {"noise": 2.0, "classes": str(path.resolve())}
    with pytest.raises(SystemExit, match="b-hard uses another table"):
        bq.with_classes(["b-hard"], path)
    path.write_text("classes: []\n")
    # the mistake is the exit message (no traceback), as quash make-scene says it
    with pytest.raises(SystemExit, match="--classes: .*mine.yaml: absent: missing"):
        bq.with_classes(["project"], path)
    with pytest.raises(SystemExit, match="--classes: .*nowhere.yaml: no such class-table file"):
        bq.with_classes(["project"], tmp_path / "nowhere.yaml")


def test_a_changed_class_table_file_is_not_reused(bq, tmp_path, monkeypatch):
    # was: the scenes and runs of the file's first version were reused, and reported
    table = tmp_path / "mine.yaml"
    table.write_text("name: mine  # first version\n")
    monkeypatch.setitem(bq.GENERATORS, "mine-project", {"classes": str(table)})
    out = tmp_path / "out"
    (out / "scenes").mkdir(parents=True)
    (out / "runs").mkdir()
    (out / "scenes" / "mine-project-seed0.npz").write_bytes(b"")
    info = out / "scenes" / "mine-project-seed0.queries.yaml"
    info.write_text(f"class_table_sha256: {hashlib.sha256(table.read_bytes()).hexdigest()}\n")
    (out / "runs" / "mine-project-seed0-closed.json").write_text('{"configs": []}')
    assert bq.run_one(out, "mine-project", 0, "closed", None, None) == {"configs": []}
    table.write_text("name: mine  # edited\n")
    for call in (
        lambda: bq.run_one(out, "mine-project", 0, "closed", None, None),
        lambda: bq.scene(out, "mine-project", 0, None, None),
    ):
        with pytest.raises(SystemExit, match=r"another version of .*mine\.yaml.*another --out"):
            call()


def test_open_queries_split_by_kind_with_their_own_means_and_absence(bq, monkeypatch):
    """The split of an open-vocabulary run: free text (the class table's descriptions)
    apart from sub-class names, each with its own per-query rows, mean, absence and
    present -> empty, and the verdict judged on each kind as on the scenario."""
    from quash_plugins.demo.classes import ABSENT_FREE_TEXT_OPEN, FREE_TEXT_A

    monkeypatch.setitem(bq.GENERATORS, "g", {})  # table A
    free, absent_free = FREE_TEXT_A["bed"], ABSENT_FREE_TEXT_OPEN[0]
    rows = {"bunk bed": (0.9, 10), "a futon": (0.7, 5), free: (0.0, 0)}

    def config(name, scale):
        per_query = {
            q: {
                "f1": f * scale,
                "precision": f,
                "recall": f,
                "iou": f,
                "ap": 0.5,
                "inv_rank": 1.0,
                "n_pred": n,
            }
            for q, (f, n) in rows.items()
        }
        absence = {"tub": {"empty": True}, absent_free: {"empty": scale < 1}}
        return {
            "name": name,
            "given": "x",
            "mean": {"f1": 0.0},
            "per_query": per_query,
            "absence": {"score": 0.5, "present_empty": 1, "per_query": absence},
        }

    configs = [config("quash-labels", 1.0), config("vlmaps-labels", 0.5)]
    rec = {"generator": "g", "seed": 0, "scenario": "open-list", "configs": configs}
    sub, text = bq.split_by_kind(rec)
    assert sub["scenario"] == "open-list, sub-class names"
    assert text["scenario"] == "open-list, free text"
    q_sub = sub["configs"][0]
    assert set(q_sub["per_query"]) == {"bunk bed", "a futon"}
    assert q_sub["mean"]["f1"] == pytest.approx((0.9 + 0.7) / 2)
    assert q_sub["absence"]["score"] == 1.0 and q_sub["absence"]["present_empty"] == 0
    q_text = text["configs"][0]
    assert set(q_text["per_query"]) == {free}
    assert set(q_text["absence"]["per_query"]) == {absent_free}
    assert q_text["absence"]["score"] == 0.0 and q_text["absence"]["present_empty"] == 1
    # a closed run is not split
    assert bq.split_by_kind({**rec, "scenario": "closed"}) == [{**rec, "scenario": "closed"}]
    # the verdict of each kind: the peer's F1 is half QuASH's on sub-class names (2.00x)
    verdict = bq.verdict(bq.summarise([sub, text]))[2:]
    cells = [[c.strip() for c in row.strip("|").split("|")] for row in verdict]
    assert cells[0][1] == "open-list, sub-class names" and cells[0][5] == "2.00x"
    assert cells[0][-1] == "yes"
    assert cells[1][1] == "open-list, free text" and cells[1][-1] == "NO"  # absence 0


@pytest.mark.parametrize("spec", ["0-4", "0,x", "0 1 2"])
def test_seeds_that_are_not_a_comma_separated_list_are_refused_with_the_form(bq, spec):
    """--seeds 0-4 ended in a ValueError traceback (invalid literal for int())."""
    with pytest.raises(SystemExit, match=r"--seeds .*comma-separated integers, e.g. --seeds 0,1"):
        bq.parse_seeds(spec)
    assert bq.parse_seeds("0,1,2,3,4") == [0, 1, 2, 3, 4]


@pytest.mark.parametrize(
    "argv",
    [["--seeds", "0-4"], ["--generators", "nope"], ["--scenarios", "closd"]],
)
def test_a_refused_run_leaves_no_out_folder(bq, tmp_path, monkeypatch, argv):
    """--out was made before the arguments were checked: a run refused for its seeds, a
    generator or a scenario left an empty folder behind (bench_ceiling.py does not)."""
    out = tmp_path / "o"
    monkeypatch.setattr(sys, "argv", ["bench_quality.py", "--out", str(out), *argv])
    with pytest.raises(SystemExit):
        bq.main()
    assert not out.exists()


def test_the_plots_say_their_dots_are_seeds(bq, tmp_path, monkeypatch):
    """The quality plots show one dot per seed and the mean over the seeds: the legend
    says so (the plot's default reads 'one query', which these dots are not)."""

    def run_one(out, gen, seed, scen, encoder, cache):
        cfgs = [
            {
                "name": name,
                "given": "x",
                "mean": {"f1": 0.5, "precision": 0.4 + seed / 10, "recall": 0.6, "ap": 0.5},
                "per_query": {"chair": {}},
                "absence": {"score": 1.0, "present_empty": 0, "per_query": {}},
            }
            for name in ("quash-labels", "vlmaps-labels")
        ]
        return {"generator": gen, "seed": seed, "scenario": scen, "seconds": 1.0, "configs": cfgs}

    drawn = []
    monkeypatch.setattr(bq, "run_one", run_one)
    monkeypatch.setattr(bq.registry, "create", lambda *a, **k: None)
    monkeypatch.setattr(
        bq, "plot_precision_recall", lambda rows, path, **kw: drawn.append((rows, kw))
    )
    argv = ["bench_quality.py", "--out", str(tmp_path / "q"), "--seeds", "0,1"]
    monkeypatch.setattr(sys, "argv", [*argv, "--generators", "project", "--scenarios", "closed"])
    bq.main()
    [(rows, kw)] = drawn
    assert kw["dots"] == "one seed" and kw["mean"] == "mean over the seeds"
    assert set(rows[0]["per_query"]) == {0, 1}  # the dots: one per seed
    assert rows[0]["mean"]["precision"] == pytest.approx((0.4 + 0.5) / 2)
