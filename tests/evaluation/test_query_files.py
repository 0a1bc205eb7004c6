"""The mistakes a new user makes in a query list or a query file are refused, naming the
file, the query and the fix, instead of silently turning a query into something else."""

from __future__ import annotations

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
            r"q\.yaml: query 'a cobot' has the label None",
        ),
        ("a cobot:\n", r"q\.yaml: query 'a cobot' has the label None"),
        (
            "presnt:\n  a cobot: robot arm\nabsent: [a giraffe]\n",
            r"q\.yaml: unknown key 'presnt'.*Did you mean 'present'\?",
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
