"""quash eval and quash make-scene end to end, with a table encoder (fast, offline)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins.cli.main import main
from quash_plugins.demo.classes import ABSENT, CLASSES
from quash_plugins.evaluation.metrics import query_metrics

NAMES = (
    {n for c in CLASSES for n in (*c.appearance, *c.language, c.label)}
    | {n for k, v in ABSENT.items() for n in (k, *v)}
    | {"other", "background", "nothing", "an elephant"}
)


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    d = tmp_path_factory.mktemp("eval")
    table = table_for(sorted(NAMES))
    np.savez(
        d / "table.npz",
        texts=np.asarray(list(table)),
        embeddings=np.asarray(list(table.values()), np.float32),
    )
    rc = main(
        [
            "make-scene",
            str(d / "scene.npz"),
            "--encoder",
            "table",
            "--encoder-file",
            str(d / "table.npz"),
            "--rooms",
            "1",
            "--voxel-size",
            "0.25",
            "--no-cache",
        ]
    )
    assert rc == 0
    enc = {"name": "table", "file": "table.npz"}
    (d / "base.yaml").write_text(
        yaml.safe_dump(
            {
                "name": "vlmaps",
                "encoder": enc,
                "heuristic": "none",
                "negatives": ["other"],
                "classifier": "contrast",
                "instances": False,
                "cache": False,
            }
        )
    )
    (d / "quash.yaml").write_text(
        yaml.safe_dump(
            {
                "name": "quash-taxonomy",
                "encoder": enc,
                "classifier": "contrast",
                "heuristic": {"name": "taxonomy", "file": "scene.taxonomy.yaml"},
                "instances": False,
                "cache": False,
            }
        )
    )
    return d


def test_eval_json_markdown_and_plot(world, tmp_path):
    out = tmp_path / "r.json"
    rc = main(
        [
            "eval",
            str(world / "scene.npz"),
            "-c",
            str(world / "base.yaml"),
            "-c",
            str(world / "quash.yaml"),
            "--absent",
            "piano,an elephant",
            "--json",
            str(out),
            "--markdown",
            str(tmp_path / "r.md"),
            "--plot",
            str(tmp_path / "r.png"),
        ]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert list(data) == ["configs", "provenance"]
    names = [c["name"] for c in data["configs"]]
    assert names == ["vlmaps", "quash-taxonomy"]
    for c in data["configs"]:
        assert set(c) == {"name", "given", "mean", "per_query", "absence"}
        assert set(c["mean"]) == {"precision", "recall", "f1", "iou", "ap", "inv_rank"}
        assert set(c["absence"]["per_query"]) == {"piano", "an elephant"}
        f1 = [q["f1"] for q in c["per_query"].values()]
        assert c["mean"]["f1"] == pytest.approx(float(np.mean(f1)))
    assert [c["given"] for c in data["configs"]] == [
        "the query alone",
        "the label list (scene.taxonomy.yaml)",
    ]
    md = (tmp_path / "r.md").read_text()
    assert "| vlmaps |" in md and "| quash-taxonomy |" in md
    assert (tmp_path / "r.png").read_bytes()[:4] == b"\x89PNG"


def test_eval_json_says_which_map_queries_and_configs_it_came_from(world, tmp_path):
    from quash_plugins import __version__
    from quash_plugins.evaluation.report import is_report_file, report_markdown

    queries = tmp_path / "q.yaml"
    queries.write_text("present:\n  couch: sofa\n  wall: wall\nabsent: [an elephant]\n")
    out = tmp_path / "r.json"
    args = ["eval", str(world / "scene.npz"), "-c", str(world / "base.yaml")]
    args += ["-c", str(world / "quash.yaml"), "--queries-file", str(queries)]
    assert main([*args, "--absent", "piano", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    prov = data["provenance"]
    assert prov["quash_plugins"] == __version__
    assert prov["map"]["path"] == str(world / "scene.npz")
    assert prov["map"]["adapter"] == "npz"
    assert prov["query_file"] == str(queries)
    assert prov["queries"] == {"couch": "sofa", "wall": "wall"}
    assert prov["absent"] == ["an elephant", "piano"]
    assert prov["configs"] == [
        {
            "name": "vlmaps",
            "file": str(world / "base.yaml"),
            "shipped": None,
            "encoder": "table",
            "templates": None,
        },
        {
            "name": "quash-taxonomy",
            "file": str(world / "quash.yaml"),
            "shipped": None,
            "encoder": "table",
            "templates": None,
        },
    ]
    assert prov["empty_tolerance"] == 0 and "void" in prov["exclude"]
    # the readers of the existing keys are unaffected
    assert [c["name"] for c in data["configs"]] == ["vlmaps", "quash-taxonomy"]
    assert "| quash-taxonomy |" in report_markdown(data["configs"])
    assert is_report_file(out)
    # no query file: null
    assert main([*args[:4], "--queries", "wall", "--json", str(out)]) == 0
    assert json.loads(out.read_text())["provenance"]["query_file"] is None


def test_eval_provenance_names_a_shipped_config_and_a_config_without_a_file(world):
    import dataclasses

    from quash_plugins import Quash, QuashConfig
    from quash_plugins.core.config import PluginSpec
    from quash_plugins.core.shipped import find_shipped
    from quash_plugins.evaluation import evaluate

    table = PluginSpec("table", {"file": str(world / "table.npz")})
    shipped = QuashConfig.from_yaml("demo:openscene-labels")
    shipped = dataclasses.replace(shipped, encoder=table, cache=False)
    plain = {"name": "plain", "encoder": table.to_dict(), "classifier": "contrast"}
    plain["prompt_templates"] = {"mode": "mean", "templates": ["{}"]}  # the table's strings
    report = evaluate(
        str(world / "scene.npz"), [Quash.from_config(shipped), plain], queries=["wall"]
    )
    assert report.provenance["configs"] == [
        {
            "name": "openscene-labels",
            "file": str(find_shipped("demo:openscene-labels").path),
            "shipped": "demo:openscene-labels",
            "encoder": "table",
            "templates": None,
        },
        {
            "name": "plain",
            "file": None,
            "shipped": None,
            "encoder": "table",
            "templates": "a list of 1 in the config",
        },
    ]
    assert report.provenance["query_file"] is None
    assert report.to_json()["provenance"] == report.provenance


def test_eval_scores_match_an_independent_query(world, tmp_path):
    """Recompute one query's metrics from `quash query`'s own mask."""
    out = tmp_path / "r.json"
    assert (
        main(
            [
                "eval",
                str(world / "scene.npz"),
                "-c",
                str(world / "base.yaml"),
                "--queries",
                "wall,floor,piano",
                "--json",
                str(out),
            ]
        )
        == 0
    )
    data = json.loads(out.read_text())["configs"][0]
    assert set(data["per_query"]) == {"wall", "floor"}
    assert "piano" in data["absence"]["per_query"]  # a label absent from the map
    assert (
        main(
            [
                "query",
                str(world / "scene.npz"),
                "wall",
                "-c",
                str(world / "base.yaml"),
                "--out",
                str(tmp_path / "q.npz"),
            ]
        )
        == 0
    )
    with np.load(tmp_path / "q.npz") as q, np.load(world / "scene.npz") as m:
        names = [str(n) for n in m["label_names"]]
        ref = query_metrics(q["masks"][0], m["labels"] == names.index("wall"))
    assert data["per_query"]["wall"]["f1"] == pytest.approx(ref["f1"])


def test_eval_without_a_config_is_the_default_and_says_when_the_map_is_not_its_encoders(
    world, capsys
):
    """No -c runs the fair comparison with the default config's encoder (MiniLM; see
    tests/cli/test_default_config.py); a map built by another encoder is refused clearly."""
    pytest.importorskip("sentence_transformers")
    assert main(["eval", str(world / "scene.npz")]) == 1
    err = capsys.readouterr().err
    assert "scene.npz" in err and "text encoder that built the map" in err


def _eval_json(world, tmp_path, *args):
    out = tmp_path / f"e{len(list(tmp_path.glob('e*.json')))}.json"
    cmd = ["eval", str(world / "scene.npz"), "-c", str(world / "base.yaml"), "--json", str(out)]
    assert main([*cmd, *args]) == 0
    return json.loads(out.read_text())["configs"][0]


def _scene_labels(world):
    with np.load(world / "scene.npz") as m:
        return m["labels"], [str(n) for n in m["label_names"]]


def test_eval_all_labels_scores_every_present_label(world, tmp_path):
    from quash_plugins.evaluation.report import DEFAULT_EXCLUDE

    labels, names = _scene_labels(world)
    present = {names[i] for i in np.unique(labels[labels >= 0])}
    expected = present - set(DEFAULT_EXCLUDE)
    assert expected and len(expected) < len(names)  # some labels are absent from the scene
    data = _eval_json(world, tmp_path, "--all-labels")
    assert set(data["per_query"]) == expected
    assert data["absence"]["per_query"] == {}
    # --all-labels is the documented default
    assert _eval_json(world, tmp_path) == data


def test_eval_all_labels_and_queries_exclude_each_other(world, capsys):
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "eval",
                str(world / "scene.npz"),
                "-c",
                str(world / "base.yaml"),
                "--all-labels",
                "--queries",
                "wall",
            ]
        )
    assert exc.value.code == 2
    assert "not allowed with argument" in capsys.readouterr().err


def test_eval_exclude_ignores_those_items_and_never_queries_them(world, tmp_path):
    """--exclude wall: wall is not queried, and a wall item in a mask is neither TP nor FP;
    checked against `quash query`'s own masks."""
    labels, names = _scene_labels(world)
    counts = {n: int((labels == i).sum()) for i, n in enumerate(names)}
    assert counts["wall"] > 0 and counts["floor"] > 0
    data = _eval_json(world, tmp_path, "--exclude", "wall")
    assert "wall" not in data["per_query"] and "floor" in data["per_query"]
    default = _eval_json(world, tmp_path)
    assert "wall" in default["per_query"]
    assert (
        main(
            [
                "query",
                str(world / "scene.npz"),
                "floor",
                "-c",
                str(world / "base.yaml"),
                "--out",
                str(tmp_path / "q.npz"),
            ]
        )
        == 0
    )
    with np.load(tmp_path / "q.npz") as q:
        mask = q["masks"][0]
    truth = labels == names.index("floor")
    wall = labels == names.index("wall")
    assert (mask & wall).any(), "the floor mask must hit walls for this test to mean anything"
    ref = query_metrics(mask, truth, valid=(labels >= 0) & ~wall)
    got = data["per_query"]["floor"]
    assert (got["tp"], got["fp"], got["fn"]) == (ref["tp"], ref["fp"], ref["fn"])
    assert got["fp"] == default["per_query"]["floor"]["fp"] - int((mask & wall).sum())


def test_eval_without_absence_queries_says_so_and_names_the_scenes_query_file(
    world, tmp_path, capsys
):
    """A map holds only the labels its items carry, so scoring every label measures no
    empty answer: eval warns, and names make-scene's SCENE.queries.yaml beside the map,
    which lists the scene's absent labels."""

    def warned():
        return [ln for ln in capsys.readouterr().err.splitlines() if "no absence query" in ln]

    queries_file = world / "scene.queries.yaml"
    absent = yaml.safe_load(queries_file.read_text())["absent"]
    assert absent  # make-scene lists the scene's absent labels there
    capsys.readouterr()
    data = _eval_json(world, tmp_path)
    said = warned()
    assert data["absence"]["per_query"] == {} and len(said) == 1
    assert said[0].startswith("WARNING") and f"--queries-file {queries_file}" in said[0]
    # with an absence query there is nothing to warn about
    data = _eval_json(world, tmp_path, "--absent", "an elephant")
    assert set(data["absence"]["per_query"]) == {"an elephant"} and not warned()
    # a map with no query file beside it: the warning names no file
    alone = tmp_path / "alone"
    alone.mkdir()
    for f in ("scene.npz", "base.yaml", "table.npz"):
        (alone / f).write_bytes((world / f).read_bytes())
    _eval_json(alone, tmp_path)
    said = warned()
    assert len(said) == 1 and "--queries-file" not in said[0]


def test_eval_markdown_says_what_an_absence_query_may_match_under_empty_tolerance(world, tmp_path):
    """With --empty-tolerance N the absence table's heading said '0 = correct', while a
    query matching up to N items was scored as correct (absence 1.000 beside a count of 7)."""
    out, md = tmp_path / "r.json", tmp_path / "r.md"
    args = ["eval", str(world / "scene.npz"), "-c", str(world / "base.yaml")]
    args += ["--queries", "wall", "--absent", "piano,bathtub", "--json", str(out)]
    assert main([*args, "--markdown", str(md)]) == 0
    assert "Items matched by absence queries (0 = correct):" in md.read_text()
    matched = json.loads(out.read_text())["configs"][0]["absence"]["per_query"]
    tol = max(v["matched"] for v in matched.values()) + 1
    assert main([*args, "--markdown", str(md), "--empty-tolerance", str(tol)]) == 0
    text = md.read_text()
    assert f"Items matched by absence queries (at most {tol} = correct):" in text
    assert "0 = correct" not in text
    absence = json.loads(out.read_text())["configs"][0]["absence"]
    assert absence["score"] == 1.0 and absence["empty_tolerance"] == tol


def test_eval_counts_its_queries_in_words_that_agree(world, capsys):
    """The line above the table read '1 queries, 1 absence queries'."""
    base = ["eval", str(world / "scene.npz"), "-c", str(world / "base.yaml")]
    labels, names = _scene_labels(world)
    have = [names[i] for i in np.unique(labels[labels >= 0])]
    assert main([*base, "--queries", have[0], "--absent", "an elephant"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert ": 1 query, 1 absence query" in out
    assert main([*base, "--queries", ",".join(have[:2])]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert ": 2 queries, 0 absence queries" in out


def test_eval_makes_the_spacing_of_absent_and_queries_single_as_a_query_file_does(world, tmp_path):
    """--absent ' an   elephant ' was queried and reported with its inner spaces (a query
    file's absent list had them made single), so the encoder saw another text."""
    data = _eval_json(world, tmp_path, "--absent", " an   elephant ")
    assert list(data["absence"]["per_query"]) == ["an elephant"]


def _scored_absent_warnings(capsys) -> list[str]:
    err = capsys.readouterr().err.splitlines()
    return [ln for ln in err if ln.startswith("WARNING") and "scored as an absence query" in ln]


def test_a_piece_of_queries_split_at_a_comma_is_warned_about_not_said_at_info(
    world, tmp_path, capsys
):
    """--queries "swivel chair, desk chair=chair" is two queries (the option splits at
    every comma); the first piece is no label of the map, so it was scored as an absence
    query with only an INFO line. It is warned about, naming the piece, --queries and
    --queries-file; the valid uses stay quiet."""
    labels, names = _scene_labels(world)
    assert "swivel chair" not in names and "chair" in names
    capsys.readouterr()
    data = _eval_json(world, tmp_path, "--queries", "swivel chair, desk chair=chair")
    assert list(data["per_query"]) == ["desk chair"]
    assert data["per_query"]["desk chair"]["label"] == "chair"
    assert list(data["absence"]["per_query"]) == ["swivel chair"]
    (said,) = _scored_absent_warnings(capsys)
    assert "--queries: query 'swivel chair' is not a label of the map" in said
    assert "a query text that holds a comma needs --queries-file" in said
    # labels, TEXT=LABEL items, and a label meant as absent listed under --absent: quiet
    have = [names[i] for i in np.unique(labels[labels >= 0])][:2]
    quiet = [
        ("--queries", ",".join(have)),
        ("--queries", "desk chair=chair,seat=chair", "--absent", "an elephant"),
        ("--queries", f"{have[0]},piano", "--absent", "piano"),
        ("--queries", f"{have[0]},grand piano=piano", "--absent", "piano"),
    ]
    for args in quiet:
        data = _eval_json(world, tmp_path, *args)
        assert data["per_query"], args
        assert not _scored_absent_warnings(capsys), args


def test_a_query_of_a_label_no_item_carries_is_warned_about_as_one_the_map_lacks_is(
    world, tmp_path, capsys
):
    """'X=LABEL' whose LABEL is in the map's label list but carried by no item became an
    absence query with only an INFO line, while a LABEL that is not in the list at all is
    warned about: a query meant as present, scored as absent, is warned about either way."""
    labels, names = _scene_labels(world)
    carried = set(np.unique(labels[labels >= 0]).tolist())
    empty = [n for i, n in enumerate(names) if i not in carried]
    (cls,) = [c for c in CLASSES if c.label == empty[0]]
    text = cls.language[0]  # an open-vocabulary query of that label
    capsys.readouterr()
    data = _eval_json(world, tmp_path, "--queries", f"{text}={cls.label},chair")
    assert list(data["per_query"]) == ["chair"]
    assert data["absence"]["per_query"][text]["label"] == cls.label
    (said,) = _scored_absent_warnings(capsys)
    assert f"query {text!r}: its label {cls.label!r} is a label that no item of the map" in said
    assert "list it under --absent" in said and "--queries-file" not in said
    # the label alone is warned about too; listed under --absent, neither is
    _eval_json(world, tmp_path, "--queries", f"{cls.label},chair")
    (said,) = _scored_absent_warnings(capsys)
    assert f"query {cls.label!r} is a label that no item of the map carries" in said
    _eval_json(world, tmp_path, "--queries", f"{text}={cls.label},chair", "--absent", cls.label)
    assert not _scored_absent_warnings(capsys)
