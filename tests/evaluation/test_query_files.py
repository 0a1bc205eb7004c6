"""The mistakes a new user makes in a query list or a query file are refused, naming the
file, the query and the fix, instead of silently turning a query into something else."""

from __future__ import annotations

import dataclasses
import json

import pytest

from quash_plugins.cli.main import main
from quash_plugins.core.errors import QuashError
from quash_plugins.evaluation.queries import load_query_file, parse_queries


def test_a_query_given_twice_with_two_labels_is_refused():
    with pytest.raises(QuashError, match=r"'a cobot' is given twice, with the labels 'robot arm'"):
        parse_queries(["a cobot=robot arm", "a cobot = locker"])
    # the same query twice with the same label is one query
    assert parse_queries(["forklift", "forklift", "a cobot=robot arm", "a  cobot=robot arm"]) == {
        "forklift": "forklift",
        "a cobot": "robot arm",
    }


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("present:\n  a cobot: [robot arm]\n", r"q\.yaml: query 'a cobot' has the label \['robot"),
        (
            "present:\n  a cobot:\nabsent: [a giraffe]\n",
            r"q\.yaml: query 'a cobot' has no label",
        ),
        ("a cobot:\n", r"q\.yaml: query 'a cobot' has no label"),
        # a label index, not a name: the item it names would be scored as absent
        ("present:\n  bunk bed: 8\n", r"q\.yaml: query 'bunk bed' has the label 8 \(int\).*index"),
        (
            "presnt:\n  a cobot: robot arm\nabsent: [a giraffe]\n",
            r"q\.yaml: unknown key 'presnt'.*Did you mean 'present'\?",
        ),
        # the same misspelling with no 'absent' beside it: the key is named, not read as
        # a query 'presnt' whose label is a mapping
        (
            "presnt:\n  a cobot: robot arm\n",
            r"q\.yaml: unknown key 'presnt'.*Did you mean 'present'\?",
        ),
        ("absnt: [a giraffe]\nchair: chair\n", r"q\.yaml: unknown key 'absnt'.*'absent'\?"),
        # a wrong type names the section that has it, not both
        (
            "present: [chair]\nabsent: a giraffe\n",
            r"q\.yaml: 'absent' is 'a giraffe'.*\[a giraffe\]",
        ),
        ("present: chair\nabsent: [a giraffe]\n", r"q\.yaml: 'present' is 'chair'; write a list"),
        # a {text: label} item inside a list, or a label index: each was read as the query
        # text "{'a seat': 'stool'}" or "5", no label of the map, so an absence query
        (
            "present:\n  - chair\n  - a seat: stool\n",
            r"q\.yaml: query item \{'a seat': 'stool'\} \(dict\) is not text.*'a seat=stool'",
        ),
        ("present: [chair, 5]\n", r"q\.yaml: query item 5 \(int\) is not text.*index"),
        ("[chair, [bed]]\n", r"q\.yaml: query item \['bed'\] \(list\) is not text"),
        (
            "present: [chair]\nabsent:\n  - a giraffe: zoo\n",
            r"q\.yaml: absence query \{'a giraffe': 'zoo'\} \(dict\) under 'absent' is not text",
        ),
        (
            "present: [chair]\nabsent: {a giraffe: zoo}\n",
            r"q\.yaml: 'absent' is \{'a giraffe': 'zoo'\}; write a list of texts \(\[a giraffe, a grand",
        ),
        # a misspelt section of labels alone (every value a list, as in a taxonomy): the
        # key is named, not the file called a taxonomy
        ("presnt: [chair, sofa]\n", r"q\.yaml: unknown key 'presnt'.*Did you mean 'present'\?"),
        (
            "presnt: [chair]\nabsnt: [a giraffe]\n",
            r"q\.yaml: unknown key 'presnt'.*Did you mean 'present'\?",
        ),
        # make-scene's taxonomy given as the query file: said so, not 'not by an index'
        (
            "bed: [bunk bed, cot]\nsofa: [couch, settee]\n",
            r"q\.yaml: this is a taxonomy .*not a query file.*SCENE\.queries\.yaml",
        ),
    ],
)
def test_query_file_mistakes_name_the_file_and_the_query(tmp_path, text, message):
    f = tmp_path / "q.yaml"
    f.write_text(text)
    with pytest.raises(QuashError, match=message):
        load_query_file(f)


def test_make_scene_query_file_keys_are_accepted(tmp_path):
    f = tmp_path / "q.yaml"
    f.write_text(
        "kind: open\npresent: [chair]\nabsent: [piano]\nroom_types: [kitchen]\n"
        "options: {seed: 0}\nclass_table_sha256: abc\n"
    )
    assert load_query_file(f) == ({"chair": "chair"}, ["piano"])


def test_cli_refuses_a_missing_query_file_and_empty_queries_before_reading_the_map(
    tmp_path, capsys
):
    missing_map = str(tmp_path / "no-map.npz")
    assert main(["eval", missing_map, "--queries-file", str(tmp_path / "nope.yaml")]) != 0
    err = capsys.readouterr().err
    assert "Query file not found" in err and "nope.yaml" in err and "Config file" not in err
    assert main(["eval", missing_map, "--queries", " , "]) != 0
    assert "--queries is empty" in capsys.readouterr().err


def _robot_map_and_peer():
    """Two 8-voxel blocks, 'robot arm' and 'forklift', and a label-argmax peer."""
    import numpy as np
    from _eval_table import table_for, vec

    from quash_plugins import LatentMap, Quash
    from quash_plugins.core import registry
    from quash_plugins.encoders import TableEncoder

    grid, rows, labels = [], [], []
    for li, (name, x0) in enumerate((("robot arm", 0), ("forklift", 10))):
        for i in range(8):
            grid.append((x0 + i % 2, i // 2 % 2, i // 4))
            rows.append(vec(name))
            labels.append(li)
    lmap = LatentMap(
        np.asarray(rows, np.float32),
        kind="voxels",
        grid_index=np.asarray(grid),
        voxel_size=0.1,
        labels=np.asarray(labels),
        label_names=["robot arm", "forklift"],
    )
    tax = {"robot arm": ["cobot"], "forklift": ["stacker"], "drone": ["quadcopter"]}
    names = {n for k, v in tax.items() for n in (k, *v)} | {"other", "background", "nothing"}
    peer = Quash(
        TableEncoder(table=table_for(names | {"a cobot", "Forklift", "a giraffe"})),
        registry.create("heuristics", "label-list", taxonomy=tax),
        registry.create("classifiers", "label-argmax"),
        negatives=["other"],
        instances=False,
        name="peer",
    )
    return lmap, peer


def test_a_label_spelt_in_another_case_is_the_maps_label():
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    rep = evaluate(lmap, [peer], queries=["a cobot=Robot Arm", "Forklift", "a giraffe=robot_arm"])
    pq = rep.configs[0]["per_query"]
    assert rep.absent == []
    assert {q: v["label"] for q, v in pq.items()} == {
        "a cobot": "robot arm",
        "Forklift": "forklift",
        "a giraffe": "robot arm",
    }
    assert pq["Forklift"]["n_true"] == 8 and pq["Forklift"]["recall"] == 1.0


def test_a_misspelt_label_is_refused_with_the_closest_names(caplog):
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    # was: warned about, then scored as an absence query (the robot arm counted as absent)
    with pytest.raises(QuashError) as err:
        evaluate(lmap, [peer], queries=["a cobot=robot amr", "Forklift"])
    msg = str(err.value)
    assert msg.startswith("Query 'a cobot': its label 'robot amr' is not a label of the map.")
    assert "Did you mean 'robot arm'?" in msg and "move the query to --absent" in msg
    with pytest.raises(QuashError, match=r"Query 'forklfit' is not a label.*'forklift'\?"):
        evaluate(lmap, [peer], queries=["forklfit"])
    # a label that is no near miss of the map's names is an object the map does not have:
    # an absence query, warned about (a query given as present, scored as absent: a label
    # alone may be a piece of a query text that held a comma)
    with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation.queries"):
        rep = evaluate(lmap, [peer], queries=["forklift", "drone", "quadcopter=drone"])
    assert rep.queries == ["forklift"] and rep.absent == ["drone", "quadcopter"]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("'quadcopter': its label 'drone' is not a label" in m for m in warned)
    assert any("query 'drone' is not a label of the map" in m for m in warned)
    # listed under --absent, neither is warned about
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation.queries"):
        evaluate(lmap, [peer], queries=["forklift", "drone", "quadcopter=drone"], absent=["drone"])
    assert not [r for r in caplog.records if r.levelno == logging.WARNING]


def test_a_misspelt_label_in_a_query_file_names_the_file(tmp_path, capsys):
    from quash_plugins.adapters._npz import write_npz_map

    lmap, _ = _robot_map_and_peer()
    write_npz_map(lmap, tmp_path / "map.npz")
    q = tmp_path / "q.yaml"
    q.write_text("present:\n  a cobot: robbot arm\n  forklift: forklift\nabsent: [a giraffe]\n")
    assert main(["eval", str(tmp_path / "map.npz"), "--queries-file", str(q)]) == 1
    err = capsys.readouterr().err
    assert f"{q}: query 'a cobot': its label 'robbot arm' is not a label of the map." in err
    assert "Did you mean 'robot arm'?" in err and f"under 'absent' in {q}" in err


def test_a_query_file_label_the_map_lacks_is_warned_about_naming_the_file(tmp_path, caplog):
    """The warning that a query file's label is no label of the map (so its query is
    scored as an absence query) did not say which file to fix, as the typo error does."""
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    q = tmp_path / "q.yaml"
    q.write_text("present:\n  quadcopter: drone\n  forklift: forklift\n")
    with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation.queries"):
        present, absent = load_query_file(q)
        rep = evaluate(lmap, [peer], queries=present, absent=absent, query_file=q)
    assert rep.queries == ["forklift"] and rep.absent == ["quadcopter"]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any(
        m.startswith(f"{q}: query 'quadcopter': its label 'drone' is not a label")
        and f"list it under 'absent' in {q}" in m
        for m in warned
    ), warned


def test_a_query_whose_label_is_listed_absent_or_carried_by_no_item_is_an_absence_query(caplog):
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    # the label is among the absence queries: the query is one too
    rep = evaluate(lmap, [peer], queries=["forklift", "quadcopter=Drone"], absent=["drone"])
    assert rep.queries == ["forklift"] and rep.absent == ["quadcopter", "drone"]
    # a label of the map that no item carries: an absence query, as before, warned about
    three = dataclasses.replace(lmap, label_names=["robot arm", "forklift", "drone"])
    with caplog.at_level(logging.INFO, logger="quash_plugins.evaluation"):
        rep = evaluate(three, [peer], queries=["forklift", "quadcopter=drone"])
    assert rep.queries == ["forklift"] and rep.absent == ["quadcopter"]
    assert any(
        r.levelno == logging.WARNING
        and "'quadcopter': its label 'drone' is a label that no item of the map carries"
        in r.getMessage()
        for r in caplog.records
    )


def test_an_absence_query_that_the_map_has_is_refused():
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    with pytest.raises(
        QuashError, match=r"'forklift' is both a present query \(the queries\) and an absence"
    ):
        evaluate(lmap, [peer], queries=["forklift"], absent=["forklift"])
    with pytest.raises(
        QuashError, match=r"Absence query 'Forklift' \(--absent\): 8 items of the map carry"
    ):
        evaluate(lmap, [peer], queries=["robot arm"], absent=["Forklift"])
    # an absent label of the list, or free text, is an absence query as before
    rep = evaluate(lmap, [peer], queries=["robot arm"], absent=["drone", "a giraffe"])
    assert rep.absent == ["drone", "a giraffe"]


def test_an_absence_query_from_a_query_file_that_the_map_has_names_the_file(tmp_path, capsys):
    from quash_plugins.adapters._npz import write_npz_map

    lmap, _ = _robot_map_and_peer()
    write_npz_map(lmap, tmp_path / "map.npz")
    q = tmp_path / "q.yaml"
    q.write_text("present: [robot arm]\nabsent: [a giraffe, Forklift]\n")
    run = ["eval", str(tmp_path / "map.npz"), "--queries-file", str(q)]
    assert main(run) == 1
    err = capsys.readouterr().err
    assert f"{q}: absence query 'Forklift' (under 'absent'): 8 items of the map carry" in err
    assert f"remove it from 'absent' in {q}." in err
    # the same query from the command line names --absent, not the file
    q.write_text("present: [robot arm]\nabsent: [a giraffe]\n")
    assert main([*run, "--absent", "Forklift"]) == 1
    err = capsys.readouterr().err
    assert "Absence query 'Forklift' (--absent): 8 items" in err and str(q) not in err
    # present and absent in the same file: both sections of the file are named
    q.write_text("present: [robot arm]\nabsent: [robot arm]\n")
    assert main(run) == 1
    err = capsys.readouterr().err
    assert f"'robot arm' is both a present query (in {q}) and an absence query " in err
    assert f"(under 'absent' in {q})" in err


def test_the_per_query_table_shows_each_open_vocabulary_querys_label():
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    md = evaluate(lmap, [peer], queries=["a cobot=robot arm", "forklift"]).to_markdown()
    assert "| query | label | peer |" in md
    assert "| a cobot | robot arm | " in md and "| forklift | forklift | " in md
    # labels alone: no label column (the demo's tables are unchanged)
    md = evaluate(lmap, [peer], queries=["robot arm", "forklift"]).to_markdown()
    assert "| query | peer |" in md and "label |" not in md


def test_with_only_absence_queries_the_means_are_na_and_the_absence_table_is_shown():
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    rep = evaluate(lmap, [peer, peer], queries=["drone"], absent=["drone", "a giraffe"])
    assert rep.queries == [] and rep.absent == ["drone", "a giraffe"]
    md = rep.to_markdown()
    row = next(ln for ln in md.splitlines() if ln.startswith("| peer |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2:8] == ["n/a"] * 6  # F1 .. inv. rank: nothing to score, not 0.000
    assert "**" not in row
    assert "Items matched by absence queries" in md and "| drone | " in md
    # the JSON says the same: null means, not 0 (a method that found nothing)
    assert set(rep.configs[0]["mean"].values()) == {None}
    assert json.loads(json.dumps(rep.to_json()))["configs"][0]["mean"]["f1"] is None
    assert rep.best()["name"] == "peer"


def test_present_to_empty_counts_a_present_query_empty_as_an_absence_query_would_be():
    """With --empty-tolerance N an absence query matching at most N items is empty; a
    present query that matched at most N items came back empty by the same rule, so the
    present -> empty column counts it (it counted only masks of 0 items)."""
    import numpy as np

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    queries = ["robot arm", "forklift"]
    for tolerance in (0, 3, 8):
        rep = evaluate(
            lmap,
            [peer],
            queries=queries,
            absent=["drone"],
            empty_tolerance=tolerance,
            keep_results=True,
        )
        matched = [int(np.count_nonzero(r.mask)) for r in rep.results["peer"]]
        present = matched[: len(queries)]
        assert min(present) > 0  # each block is found: only a tolerance makes it "empty"
        ab = rep.configs[0]["absence"]
        assert ab["per_query"]["drone"]["empty"] == (matched[-1] <= tolerance)
        assert ab["present_empty"] == sum(n <= tolerance for n in present)
        row = next(ln for ln in rep.to_markdown().splitlines() if ln.startswith("| peer |"))
        assert row.rstrip(" |").endswith(f"{ab['present_empty']}/{len(queries)}")
    assert ab["present_empty"] == len(queries)  # 8 items each, at most 8: both empty


def test_the_plot_of_a_report_with_only_absence_queries_is_not_written(tmp_path, capsys):
    from quash_plugins.evaluation import evaluate
    from quash_plugins.evaluation.plot import plot_precision_recall

    lmap, peer = _robot_map_and_peer()
    rep = evaluate(lmap, [peer], queries=[], absent=["drone"])
    # the library plots the configs that have a mean and skips the others (was: a TypeError)
    assert plot_precision_recall(rep.configs, tmp_path / "pr.png").exists()
    import yaml
    from _eval_table import table_for

    from quash_plugins.adapters._npz import write_npz_map

    write_npz_map(lmap, tmp_path / "map.npz")
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(table_for(["drone", "other"])))
    cfg = {
        "encoder": {"name": "table", "file": str(tmp_path / "table.yaml")},
        "heuristic": {"name": "none"},
        "classifier": {"name": "label-argmax"},
        "negatives": ["other"],
        "instances": False,
    }
    (tmp_path / "peer.yaml").write_text(yaml.safe_dump(cfg))
    (tmp_path / "q.yaml").write_text("absent: [drone]\n")
    code = main(["eval", str(tmp_path / "map.npz"), "-c", str(tmp_path / "peer.yaml"),
                 "--queries-file", str(tmp_path / "q.yaml"),
                 "--plot", str(tmp_path / "cli.png")])  # fmt: skip
    assert code == 0 and not (tmp_path / "cli.png").exists()
    assert "no present query to score" in capsys.readouterr().err


def test_a_query_of_an_excluded_label_and_a_negative_tolerance_are_refused(tmp_path, capsys):
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    # was: scored as an absence query, 'labels absent from the map'
    with pytest.raises(QuashError, match=r"Query 'forklift': its label 'forklift' is excluded"):
        evaluate(lmap, [peer], queries=["forklift", "robot arm"], exclude=["forklift"])
    missing_map = str(tmp_path / "no-map.npz")
    assert main(["eval", missing_map, "--empty-tolerance", "-1"]) != 0
    assert "--empty-tolerance takes N >= 0" in capsys.readouterr().err


def test_a_query_file_that_is_a_pipe_or_a_folder_is_named_as_such(tmp_path):
    """A FIFO given as --queries-file is refused at once (reading it would wait for a
    writer for ever), and said to be a pipe, not 'not found'."""
    import os

    from quash_plugins.evaluation.queries import load_query_file

    fifo = tmp_path / "q.yaml"
    os.mkfifo(fifo)
    with pytest.raises(QuashError) as err:
        load_query_file(fifo)
    assert "not found" not in str(err.value) and str(fifo) in str(err.value)
    with pytest.raises(QuashError) as err:
        load_query_file(tmp_path)
    assert "not found" not in str(err.value) and "uery file" in str(err.value)
    with pytest.raises(QuashError, match="Query file not found"):
        load_query_file(tmp_path / "missing.yaml")


@pytest.mark.parametrize(
    ("items", "message"),
    [
        (["a=b=bed"], r"Query item 'a=b=bed' holds more than one '='"),
        (["=bed"], r"Query item '=bed' has an empty query text"),
        (["bunk bed="], r"Query item 'bunk bed=' has an empty label"),
    ],
)
def test_malformed_text_label_items_are_refused_and_named(items, message):
    from quash_plugins.core.errors import QuashError
    from quash_plugins.evaluation.queries import parse_queries

    with pytest.raises(QuashError, match=message):
        parse_queries(items)


def test_a_query_file_with_no_query_names_the_file_not_the_maps_labels(tmp_path, capsys):
    """A query file whose 'present' and 'absent' are empty was refused as 'the map has no
    label left after --exclude', blaming the map; the error names the file and the fix."""
    from quash_plugins.adapters import write_npz_map

    lmap, _ = _robot_map_and_peer()
    path = write_npz_map(lmap, tmp_path / "m.npz")
    f = tmp_path / "q.yaml"
    f.write_text("present: {}\nabsent: []\n")
    assert main(["eval", str(path), "--queries-file", str(f)]) != 0
    err = " ".join(capsys.readouterr().err.split())
    assert f"{f} holds no present and no absent query" in err
    assert "--exclude" not in err


def test_a_query_file_given_as_a_taxonomy_is_named_as_such(tmp_path):
    """A query file holding only present: [...] and absent: [...] loaded as a taxonomy
    with the labels 'present' and 'absent' (quash bench --taxonomy, heuristic file:)."""
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.evaluation.queries import QUERY_FILE_INFO
    from quash_plugins.heuristics._taxonomy import _QUERY_FILE_KEYS, load_taxonomy

    assert {"present", "absent", *QUERY_FILE_INFO} == _QUERY_FILE_KEYS  # kept in step
    f = tmp_path / "s.queries.yaml"
    f.write_text("present: [bed, sofa]\nabsent: [piano]\nkind: closed\n")
    with pytest.raises(ConfigError, match=r"s\.queries\.yaml: this is a query file"):
        load_taxonomy(str(f))
    # a taxonomy that happens to have a label 'present' beside others still loads
    g = tmp_path / "t.yaml"
    g.write_text("present: [gift]\nbed: [cot]\n")
    assert load_taxonomy(str(g)) == {"present": ["gift"], "bed": ["cot"]}


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"queries": "bed"}, r"queries is the text 'bed', not a list.*queries=\['bed'\]"),
        ({"queries": ["bed"], "absent": "piano"}, r"absent is the text 'piano', not a list"),
        ({"queries": ["bed"], "exclude": "wall"}, r"exclude is the text 'wall', not a list"),
    ],
)
def test_a_query_list_given_as_one_string_is_refused(kwargs, message):
    """evaluate(map, configs, absent="piano") scored the absence queries 'p', 'i', 'a',
    'n' and 'o' (a string is iterated letter by letter), and queries="bed" no presence
    query at all, with nothing said."""
    import numpy as np

    from quash_plugins.core.types import LatentMap
    from quash_plugins.evaluation.report import plan_queries

    lmap = LatentMap(
        np.eye(4, dtype=np.float32), labels=np.array([0, 0, 1, 1]), label_names=["bed", "wall"]
    )
    with pytest.raises(QuashError, match=message):
        plan_queries(lmap, **kwargs)


def test_one_config_given_in_place_of_the_list_is_refused(tmp_path):
    """evaluate(map, "demo:quash-labels") iterated the name and read "Config file not
    found: d."; a dict config looked for a file named after its first key."""
    import numpy as np

    from quash_plugins.core.types import LatentMap
    from quash_plugins.evaluation import evaluate

    lmap = LatentMap(
        np.eye(4, dtype=np.float32), labels=np.array([0, 0, 1, 1]), label_names=["bed", "wall"]
    )
    with pytest.raises(
        QuashError, match=r"configs is one str, not a list.*\['demo:quash-labels'\]"
    ):
        evaluate(lmap, "demo:quash-labels")
    with pytest.raises(QuashError, match=r"configs is one dict, not a list.*configs=\[config\]"):
        evaluate(lmap, {"classifier": "contrast"})
    lmap2, peer = _robot_map_and_peer()
    with pytest.raises(QuashError, match=r"configs is one Quash, not a list"):
        evaluate(lmap2, peer)
    assert evaluate(lmap2, [peer], queries=["forklift"]).queries == ["forklift"]


def test_a_reports_repr_is_one_line_of_each_configs_f1_and_absence():
    """print(report) printed every config's per-query dict; it is now one line: what was
    scored on which map, and each config's mean F1 and absence."""
    from quash_plugins.evaluation.report import EvalReport

    def config(name, f1, absence):
        per_query = {"chair": {"f1": f1, "recall": 0.5}, "sofa": {"f1": f1, "recall": 0.5}}
        return {
            "name": name,
            "mean": {"f1": f1, "recall": 0.5},
            "per_query": per_query,
            "absence": {"score": absence, "per_query": {"piano": {"empty": absence == 1}}},
        }

    report = EvalReport(
        [config("quash-labels", 0.8234, 1.0), config("vlmaps-labels", 0.4811, 0.0)],
        ["chair", "sofa"],
        ["piano"],
        provenance={"map": {"path": "scene.npz"}},
    )
    assert repr(report) == (
        "EvalReport(2 configs x 2 queries + 1 absent on scene.npz: "
        "quash-labels F1 0.823 absence 1.00; vlmaps-labels F1 0.481 absence 0.00)"
    )
    bare = EvalReport([{"name": "c", "mean": {"f1": None}}], ["chair"], [])
    assert repr(bare) == "EvalReport(1 config x 1 query: c F1 -)"


def test_queries_given_twice_in_another_case_or_spacing_are_scored_once(caplog):
    """--absent piano,Piano scored the absence query twice and counted it twice in the
    absence score; --queries chair,Chair did the same in the macro mean. Each is one query
    (its first spelling), with one warning naming the others."""
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    once = evaluate(lmap, [peer], queries=["forklift", "a cobot=robot arm"], absent=["drone"])
    with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation"):
        rep = evaluate(
            lmap,
            [peer],
            queries=["forklift", "Forklift", "a cobot=robot arm", "A  Cobot=Robot Arm"],
            absent=["drone", "Drone", " drone ", "drone"],
        )
    assert rep.queries == once.queries == ["forklift", "a cobot"]
    assert rep.absent == once.absent == ["drone"]
    assert rep.configs[0]["absence"] == once.configs[0]["absence"]
    assert rep.configs[0]["mean"] == once.configs[0]["mean"]
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    absence = [m for m in warned if m.startswith("absence queries given more than once")]
    assert len(absence) == 1 and "'drone' (also 'Drone', ' drone ')" in absence[0]
    present = [m for m in warned if m.startswith("queries given more than once")]
    assert len(present) == 1
    assert (
        "'forklift' (also 'Forklift')" in present[0] and "'a cobot' (also 'A Cobot')" in present[0]
    )
    # the same text in another case with another label is refused, as the same text is
    with pytest.raises(QuashError, match=r"'a cobot' is given twice \(as 'A Cobot'\), with"):
        parse_queries(["a cobot=robot arm", "A Cobot=locker"])


def test_the_log_says_a_querys_label_is_not_a_label_of_the_map_not_that_no_item_carries_it(
    caplog,
):
    """--queries "grand piano=piano" on a map with no label 'piano' warned rightly, then
    said at INFO that piano is a label "no item of the map carries": it is no label."""
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    assert "drone" not in lmap.label_names
    with caplog.at_level(logging.INFO, logger="quash_plugins.evaluation"):
        rep = evaluate(lmap, [peer], queries=["forklift", "quadcopter=drone", "drone"])
    assert rep.absent == ["quadcopter", "drone"]
    said = [r.getMessage() for r in caplog.records]
    assert not any("no item of the map carries" in m for m in said), said
    # the TEXT=LABEL query and the label alone are warned about, accurately
    assert any("'quadcopter': its label 'drone' is not a label of the map" in m for m in said)
    assert any("query 'drone' is not a label of the map" in m for m in said)
    # listed absent, the TEXT=LABEL query is not warned about: the INFO line names it
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins.evaluation"):
        evaluate(lmap, [peer], queries=["forklift", "quadcopter=drone"], absent=["drone"])
    said = [r.getMessage() for r in caplog.records]
    assert any(
        m.endswith("not a label of the map, scored as absence queries: quadcopter") for m in said
    )
    assert not any("no item of the map carries" in m for m in said), said
    # a label of the map that no item carries is still said to be one (warned about, and
    # at INFO when it is listed absent)
    three = dataclasses.replace(lmap, label_names=[*lmap.label_names, "drone"])
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins.evaluation"):
        evaluate(three, [peer], queries=["forklift", "quadcopter=drone"])
    said = [r.getMessage() for r in caplog.records]
    assert any("'drone' is a label that no item of the map carries" in m for m in said)
    assert not any("not a label of the map" in m for m in said), said
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins.evaluation"):
        evaluate(three, [peer], queries=["forklift", "quadcopter=drone"], absent=["drone"])
    said = [r.getMessage() for r in caplog.records]
    assert any(
        m.endswith("no item of the map carries, scored as absence queries: quadcopter")
        for m in said
    )
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_an_open_vocabulary_absence_query_keeps_its_label_in_the_report():
    """'quadcopter=drone' on a map without drones is an absence query; the absence table,
    the JSON and provenance.absent said 'quadcopter' alone, as if it were free text."""
    import json

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    queries = ["forklift", "quadcopter=drone"]
    labelled = dict(q.split("=") for q in queries if "=" in q)
    rep = evaluate(lmap, [peer], queries=queries, absent=["a giraffe"])
    # scored as before: the text is the query, as if it were given under --absent
    plain = evaluate(lmap, [peer], queries=["forklift"], absent=[*labelled, "a giraffe"])
    assert rep.absent == plain.absent == [*labelled, "a giraffe"]
    ab, ab0 = rep.configs[0]["absence"], plain.configs[0]["absence"]
    assert ab["score"] == ab0["score"]
    for q, row in ab["per_query"].items():
        assert {k: v for k, v in row.items() if k != "label"} == ab0["per_query"][q]
        assert row.get("label") == labelled.get(q)
    data = json.loads(json.dumps(rep.to_json()))
    assert data["provenance"]["absent"] == rep.absent
    assert data["provenance"]["absent_labels"] == labelled
    assert plain.provenance["absent_labels"] == {}
    md = rep.to_markdown()
    assert "| absence query | label | peer |" in md
    for q, label in labelled.items():
        assert f"| {q} | {label} | " in md
    assert "| a giraffe |  | " in md
    # free text alone: no label column (the demo's tables are unchanged)
    assert "| absence query | peer |" in plain.to_markdown()
