"""The config a command runs with no -c: one source (core/config.py), safe on any map.

`quash query scene.npz chair` used to match half the map (the query against three
generic words). Now it is the chosen method on the map's label list, or the shipped
vocabulary when the map has none, with the presence check: it must not match most of
the map, and an object that is not there comes back empty.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins import LatentMap
from quash_plugins.core.config import DEFAULT_CONFIG, QuashConfig
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.core.shipped import find_shipped
from quash_plugins.encoders import TableEncoder
from quash_plugins.heuristics import AutoHeuristic
from quash_plugins.heuristics._vocabulary import load_vocabulary


def _without_labels(lmap: LatentMap, path):
    """The same voxel map without labels or label names, and nothing beside it."""
    from quash_plugins.adapters import write_npz_map

    return write_npz_map(
        LatentMap(
            np.asarray(lmap.embeddings),
            kind="voxels",
            positions=lmap.positions,
            grid_index=lmap.grid_index,
            voxel_size=lmap.voxel_size,
        ),
        path,
    )


def test_the_default_is_one_config_in_core_and_the_chosen_method():
    cfg = QuashConfig.default()
    assert cfg.to_dict() == QuashConfig.from_dict(DEFAULT_CONFIG).to_dict()
    assert cfg.heuristic.name == "auto" and cfg.presence is not None and cfg.refine
    # the chosen method ships as demo-quash-labels.yaml: the same classifier, refinement
    # and presence check (its YAML spells out the presence defaults)
    from quash_plugins.engine.presence import PresenceOptions

    shipped = QuashConfig.from_yaml(find_shipped("demo:quash-labels").path)
    assert shipped.classifier.to_dict() == cfg.classifier.to_dict()
    # refinement's seeds, the growth check and keep_like are "auto": the label list's settings for
    # a query set with label groups (tested on maps below)
    assert shipped.refine == {**cfg.refine, "seeds": "top"}
    assert PresenceOptions.parse(shipped.presence) == PresenceOptions.parse(
        {**cfg.presence, "grow_margin": 0.0, "keep_like": 0.6}
    )
    assert shipped.heuristic.name == "taxonomy" and shipped.heuristic.params["n_antonyms"] == "all"
    vocabulary = QuashConfig.from_yaml(find_shipped("demo:quash-vocabulary").path)
    from quash_plugins.engine.refine import RefineOptions

    assert RefineOptions.parse(vocabulary.refine) == RefineOptions.parse(
        {**cfg.refine, "seeds": "matched"}
    )
    assert PresenceOptions.parse(vocabulary.presence) == PresenceOptions.parse(
        {**cfg.presence, "grow_margin": None, "keep_like": None}
    )


@pytest.mark.slow
def test_the_default_answers_as_the_measured_configs(minilm_scene, tmp_path):
    """On a map with a label list the default's answers are demo:quash-labels' (masks and
    scores equal); on the same map without one, demo:quash-vocabulary's: what the
    quality tables measure is what `quash query MAP QUERY` does."""
    from quash_plugins import Quash
    from quash_plugins.adapters import read_map

    bare_path = _without_labels(read_map(minilm_scene, "npz"), tmp_path / "bare.npz")
    queries = ["chair", "sofa", "a bunk bed", "piano"]
    default = Quash.from_config(QuashConfig.default())
    for path, shipped in (
        (minilm_scene, "demo:quash-labels"),
        (bare_path, "demo:quash-vocabulary"),
    ):
        measured = Quash.from_config(find_shipped(shipped).path)
        ours = default.query_many(str(path), queries)
        theirs = measured.query_many(str(path), queries)
        for a, b in zip(ours, theirs):
            assert a.queryset.positives == b.queryset.positives, (shipped, a.query)
            assert a.queryset.negatives == b.queryset.negatives, (shipped, a.query)
            np.testing.assert_array_equal(a.mask, b.mask, err_msg=f"{shipped} {a.query}")
            np.testing.assert_array_equal(a.scores, b.scores, err_msg=f"{shipped} {a.query}")
        refined = [r.queryset.provenance.get("refine", {}).get("seeds") for r in ours]
        assert set(refined) <= {"top" if shipped == "demo:quash-labels" else "matched", None}


def test_the_cli_loads_the_default_without_c():
    from quash_plugins.cli._config_opts import load_config

    assert load_config(None).to_dict() == QuashConfig.default().to_dict()


def test_auto_uses_the_label_list_when_the_map_has_one_else_the_vocabulary():
    names = load_vocabulary(None)
    enc = TableEncoder(table=table_for({*names, "chair", "table", "sofa", "an elephant"}))
    h = AutoHeuristic()
    labelled = h.expand("chair", ExpansionContext(encoder=enc, label_names=["chair", "sofa"]))
    assert labelled.provenance["auto"] == "label list"
    assert labelled.negatives == ["sofa"]
    bare = h.expand("chair", ExpansionContext(encoder=enc))
    assert bare.provenance["auto"] == "vocabulary"
    assert len(bare.negatives) > 500 and "chair" not in bare.negatives


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_quash_query_without_c_is_safe_on_make_scene_maps(seed, tmp_path, capsys):
    """On tiny make-scene maps of several seeds (real MiniLM): the default finds chairs
    without matching most of the map, and returns nothing for objects that are not there,
    with the map's label list and without it (label names removed: the vocabulary)."""
    pytest.importorskip("sentence_transformers")
    from quash_plugins.adapters import read_map
    from quash_plugins.cli.main import main

    out = tmp_path / "scene.npz"
    args = ["make-scene", str(out), "--seed", str(seed), "--rooms", "2", "--voxel-size", "0.2"]
    assert main([*args, "--no-cache"]) == 0
    lmap = read_map(out, "npz")
    labels = np.asarray(lmap.labels)
    chair_share = float(np.mean(labels == lmap.label_names.index("chair")))
    bare = _without_labels(lmap, tmp_path / "bare.npz")
    capsys.readouterr()
    for path, label_list in ((out, True), (bare, False)):
        queries = ["chair", "piano", "an elephant"]
        assert main(["query", str(path), *queries, "--json"]) == 0
        res = {r["query"]: r for r in json.loads(capsys.readouterr().out)["results"]}
        assert res["chair"]["share"] < max(0.1, 5 * chair_share), (label_list, res["chair"])
        assert res["piano"]["matched"] == 0 and res["an elephant"]["matched"] == 0, label_list
        # the presence check says why a mask is empty
        assert res["piano"]["presence"].startswith("absent"), res["piano"]
        if label_list:  # with the label list, chairs are found
            assert res["chair"]["matched"] > 0
            assert res["chair"]["presence"].startswith("present"), res["chair"]
    assert main(["query", str(out), "chair", "piano"]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"^piano\s.*\sabsent\s*$", printed, re.M), printed
    # the taxonomy make-scene writes is read beside the map
    tax = yaml.safe_load((tmp_path / "scene.taxonomy.yaml").read_text())
    assert "piano" in tax


@pytest.mark.slow
def test_quash_eval_without_c_runs_the_fair_comparison(tmp_path):
    """`quash eval MAP` with no -c: the fair peers given the map's label list and the
    default config, each row saying what it was given."""
    pytest.importorskip("sentence_transformers")
    from quash_plugins.cli.main import main

    scene = tmp_path / "scene.npz"
    args = ["make-scene", str(scene), "--rooms", "2", "--voxel-size", "0.25", "--no-cache"]
    assert main(args) == 0
    out = tmp_path / "eval.json"
    assert main(["eval", str(scene), "--queries", "chair,bed", "--json", str(out)]) == 0
    rows = {c["name"]: c for c in json.loads(out.read_text())["configs"]}
    assert list(rows) == ["vlmaps-labels", "openscene-labels", "default"]
    givens = {c["given"] for c in rows.values()}
    assert len(givens) == 1 and next(iter(givens)).startswith("the label list")
    default = rows["default"]
    assert "chair" in default["per_query"]  # a query with no item is an absence query
    assert {*default["per_query"], *default["absence"]["per_query"]} == {"chair", "bed"}
