"""A query is the same query whatever its case and spacing: one listed as present and
again, in another case, as absent is refused naming both spellings; and the evaluation
modules share that rule through public names, not each other's private helpers."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from test_query_files import _robot_map_and_peer

from quash_plugins.cli.main import main
from quash_plugins.core.errors import QuashError
from quash_plugins.evaluation import queries as queries_module


@pytest.mark.parametrize(
    ("present", "absent", "message"),
    [
        # an open-vocabulary text, absent in another case: it was scored both ways
        (
            ["a cobot=robot arm"],
            ["A  Cobot"],
            "'a cobot' is a present query (the queries) and 'A  Cobot', the same query in "
            "another case or spacing, an absence query (--absent): remove it from one of them.",
        ),
        # a label the map's items carry: said so, and the present spelling named too
        (
            ["Forklift"],
            ["forklift"],
            "Absence query 'forklift' (--absent): 8 items of the map carry the label "
            "'forklift', so it is not absent; 'Forklift' is a present query (the queries) and "
            "'forklift', the same query in another case or spacing, an absence query "
            "(--absent). Absence queries name objects the map does not have; remove it from "
            "--absent.",
        ),
        # the same spelling keeps its message
        (
            ["a cobot=robot arm"],
            ["a cobot"],
            "'a cobot' is both a present query (the queries) and an absence query (--absent)",
        ),
    ],
)
def test_a_present_query_listed_absent_in_another_case_is_refused(present, absent, message):
    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    with pytest.raises(QuashError) as err:
        evaluate(lmap, [peer], queries=present, absent=absent)
    assert message in str(err.value)


def test_a_query_file_listing_a_query_present_and_absent_in_another_case_names_both(
    tmp_path, capsys
):
    from quash_plugins.adapters._npz import write_npz_map

    lmap, _ = _robot_map_and_peer()
    write_npz_map(lmap, tmp_path / "map.npz")
    q = tmp_path / "q.yaml"
    q.write_text("present:\n  A Cobot: robot arm\nabsent: [a giraffe, a cobot]\n")
    assert main(["eval", str(tmp_path / "map.npz"), "--queries-file", str(q)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert (
        f"'A Cobot' is a present query (in {q}) and 'a cobot', the same query in another "
        f"case or spacing, an absence query (under 'absent' in {q})"
    ) in err


def test_an_absent_text_whose_present_twin_is_itself_absent_is_still_one_query(caplog):
    """A present TEXT=LABEL whose label the map lacks is an absence query itself: the same
    text under --absent in another case is that query again, scored once, not refused."""
    import logging

    from quash_plugins.evaluation import evaluate

    lmap, peer = _robot_map_and_peer()
    with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation"):
        rep = evaluate(
            lmap, [peer], queries=["robot arm", "a giraffe=giraffe"], absent=["A Giraffe"]
        )
    assert rep.queries == ["robot arm"]
    assert rep.absent == ["a giraffe"]


def test_spelling_and_label_key_are_the_rules_the_query_lists_use():
    assert queries_module.spelling(" A  Cobot ") == queries_module.spelling("a cobot")
    assert queries_module.spelling("robot_arm") != queries_module.spelling("robot arm")
    assert queries_module.label_key("Robot_Arm") == queries_module.label_key("robot  arm")
    kept, twice = queries_module.one_per_spelling(["a cobot", "A  Cobot"])
    assert kept == ["a cobot"] and twice == {"a cobot": ["A  Cobot"]}


def test_no_evaluation_module_imports_another_modules_private_name():
    """report.py imported queries._fold: a private helper used across modules is a
    public name of the module that owns it."""
    folder = Path(queries_module.__file__).parent
    private = []
    for path in sorted(folder.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level:
                private += [
                    f"{path.name}: from {'.' * node.level}{node.module} import {a.name}"
                    for a in node.names
                    if a.name.startswith("_")
                ]
    assert private == []


def test_an_excluded_label_is_excluded_in_any_case_as_a_querys_label_is_matched():
    """--exclude other dropped the items of 'other' but not of 'Other', and refused the
    query 'stuff=other' but scored 'stuff=Other' as an absence query."""
    import dataclasses

    import numpy as np

    from quash_plugins.evaluation import evaluate, valid_items

    labels = np.array([0, 1, 1, 2, -1])
    assert valid_items(labels, ["chair", "Void", "Robot_Arm"], ["void", "robot arm"]).tolist() == [
        True,
        False,
        False,
        False,
        False,
    ]
    lmap, peer = _robot_map_and_peer()
    with pytest.raises(QuashError, match=r"Query 'stuff': its label 'Other' is excluded"):
        evaluate(lmap, [peer], queries=["robot arm", "stuff=Other"])
    # a map whose label is spelt 'Other': its items are ignored and it is not queried
    other = dataclasses.replace(lmap, label_names=["robot arm", "Other"])
    rep = evaluate(other, [peer])
    assert rep.queries == ["robot arm"] and rep.absent == []
    pq = rep.configs[0]["per_query"]["robot arm"]
    assert pq["n_true"] == 8 and pq["fp"] == 0  # the 8 'Other' voxels count for nothing


def test_absence_queries_given_twice_name_the_query_file_and_absent_they_came_from(
    tmp_path, caplog
):
    """The warning about absence queries given twice named no file, while the one about
    present queries did: with a query file it names the file, and --absent beside it."""
    import logging

    from quash_plugins.evaluation.report import plan_queries

    lmap, _ = _robot_map_and_peer()
    q = str(tmp_path / "q.yaml")

    def warned(**kwargs):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation"):
            plan_queries(lmap, queries=["robot arm"], **kwargs)
        said = [r.getMessage() for r in caplog.records if "absence queries given" in r.message]
        assert len(said) == 1
        return said[0]

    both = ["a giraffe", "A Giraffe"]
    said = warned(absent=both, query_file=q, absent_in_file=both)
    assert said.startswith(f"{q}: absence queries given more than once")
    said = warned(absent=both, query_file=q, absent_in_file=both[:1])
    assert said.startswith(f"{q} and --absent: absence queries given more than once")
    assert "'a giraffe' (also 'A Giraffe')" in said
    # without a query file, as before: the queries and --absent
    assert warned(absent=both).startswith("absence queries given more than once")


def test_a_query_whose_label_the_map_lacks_listed_absent_itself_is_not_warned_about(caplog):
    """The warning said 'list it under --absent to say so'; listing the query there (in any
    case) still warned. It is one absence query, said once."""
    import logging

    from quash_plugins.evaluation.report import plan_queries

    lmap, _ = _robot_map_and_peer()

    def warned(**kwargs):
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="quash_plugins.evaluation"):
            out = plan_queries(lmap, queries=["robot arm", "a Giraffe=giraffe"], **kwargs)
        return [
            r.getMessage() for r in caplog.records if "not a label of the map" in r.message
        ], out

    said, _ = warned()
    assert len(said) == 1 and "query 'a Giraffe': its label 'giraffe'" in said[0]
    for listed in (["a Giraffe"], ["A  giraffe"], ["giraffe"]):
        said, (_, _, _, presence, absence) = warned(absent=listed)
        assert said == [] and presence == ["robot arm"]
        assert absence[0] == "a Giraffe"
