"""Appearance names that read as an absent label (``quash_plugins.demo.lookalikes``)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins.cli import cmd_eval
from quash_plugins.core import yaml_files
from quash_plugins.demo.classes import SceneClass
from quash_plugins.demo.lookalikes import absent_lookalikes
from quash_plugins.demo.scene import SceneOptions, class_set, make_scene, write_scene
from quash_plugins.encoders import TableEncoder
from quash_plugins.evaluation.queries import load_query_file, query_file_lookalikes

OPTS = dict(rooms=2, voxel_size=0.25, room_size=4.0, extra_objects=1)


def _unit(v):
    v = np.asarray(v, np.float64)
    return (v / np.linalg.norm(v)).tolist()


def test_finds_the_appearance_name_nearer_an_absent_label():
    # floor-like and aquarium-like axes; "tiles" leans to the aquarium's "terrarium"
    table = {
        "floor": _unit([1, 0, 0]),
        "ground": _unit([1, 0.1, 0]),
        "planks": _unit([1, 0.2, 0]),
        "tiles": _unit([0.3, 1, 0]),
        "aquarium": _unit([0, 0.3, 1]),
        "terrarium": _unit([0.1, 1, 0]),
        "desk": _unit([0, 0, 1]),
        "bureau": _unit([0.05, 0, 1]),
        "writing top": _unit([0.1, 0.05, 1]),
    }
    enc = TableEncoder(table=table)
    classes = [
        SceneClass("floor", ("planks", "tiles"), ("ground",), (0, 0, 0), "structure"),
        SceneClass("desk", ("writing top",), ("bureau",), (0, 0, 0), "floor"),
    ]
    found = absent_lookalikes(classes, {"aquarium": ("terrarium",)}, enc)
    assert [(x.label, x.appearance, x.absent, x.absent_name) for x in found] == [
        ("floor", "tiles", "aquarium", "terrarium")
    ]
    # the cosines, computed here from the table
    t, own = np.asarray(table["tiles"]), [np.asarray(table[n]) for n in ("floor", "ground")]
    assert found[0].cosine == pytest.approx(float(t @ np.asarray(table["terrarium"])), abs=1e-6)
    assert found[0].own_cosine == pytest.approx(max(float(t @ o) for o in own), abs=1e-6)
    assert found[0].own_name == "ground"
    assert "nearer the absent 'aquarium'" in found[0].words()
    # a lead larger than the gap finds nothing; no absent labels, nothing to find
    gap = found[0].cosine - found[0].own_cosine
    assert absent_lookalikes(classes, {"aquarium": ("terrarium",)}, enc, lead=gap + 0.01) == []
    assert absent_lookalikes(classes, {}, enc) == []


def _tiny(appearance_of_floor: str) -> dict:
    c = [
        ("floor", [appearance_of_floor], ["ground"], "structure"),
        ("wall", ["painted plaster"], ["partition"], "structure"),
        ("ceiling", ["ceiling grid"], ["roof"], "structure"),
        ("door", ["oak door leaf"], ["doorway"], "wall"),
        ("window", ["glazed pane"], ["casement"], "wall"),
        ("desk", ["writing surface with drawers"], ["workstation"], "floor"),
    ]
    return {
        "name": "tiny",
        "classes": [
            {"label": a, "appearance": b, "language": d, "color": [10 * i, 0, 0], "place": p}
            for i, (a, b, d, p) in enumerate(c)
        ],
        "absent": {"aquarium": ["terrarium"]},
        "absent_free_text": ["an elephant"],
        "supports": ["desk"],
        "room_types": {"office": ["desk"]},
        "free_text": {"desk": "where to write"},
        "wall_bottom": ["door"],
        "wall_top": [],
    }


def _table(data: dict) -> dict[str, list[float]]:
    """Hashed random vectors for every name, each appearance name a copy of its label's
    (its own class's nearest name at cosine 1, so only an edit can read as absent)."""
    names = set()
    for c in data["classes"]:
        names |= {c["label"], *c["appearance"], *c["language"]}
    for k, v in data["absent"].items():
        names |= {k, *v}
    table = table_for(names)
    for c in data["classes"]:
        for a in c["appearance"]:
            table[a] = table[c["label"]]
    return table


def test_make_scene_warns_and_records_it(tmp_path, caplog):
    data = _tiny("fish tank gravel")
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    table = _table(data)
    table["fish tank gravel"] = table["terrarium"]  # reads exactly as the absent label
    opts = SceneOptions(**OPTS, classes=str(path))
    with caplog.at_level(logging.WARNING, logger="quash_plugins.demo.lookalikes"):
        s = make_scene(TableEncoder(table=table), opts)
    assert [x["appearance"] for x in s.absent_lookalikes] == ["fish tank gravel"]
    assert s.absent_lookalikes[0]["cosine"] == pytest.approx(1.0, abs=1e-4)
    assert any("'fish tank gravel' of 'floor'" in r.message for r in caplog.records)
    write_scene(s, tmp_path / "s.npz", opts)
    for name in ("s.queries.yaml", "s.open-queries.yaml"):
        info = yaml.safe_load((tmp_path / name).read_text())
        assert info["absent_lookalikes"][0]["absent"] == "aquarium"
        # quash eval --queries-file reads the file, and warns about the look-alike
        present, absent = load_query_file(tmp_path / name)
        assert present and absent
        assert query_file_lookalikes(tmp_path / name) == {"aquarium": ["fish tank gravel (floor)"]}
        args = argparse.Namespace(
            queries=None, absent=None, queries_file=str(tmp_path / name), empty_tolerance=0
        )
        caplog.clear()
        with (
            caplog.at_level(logging.WARNING, logger="quash_plugins.cli.cmd_eval"),
            mock.patch.object(yaml_files, "load_yaml", wraps=yaml_files.load_yaml) as load,
        ):
            _, absent_queries, _ = cmd_eval._queries(args)
        assert absent_queries == absent
        assert load.call_count == 1  # the queries and their look-alikes come from one read
        assert any("fish tank gravel (floor)" in r.message for r in caplog.records)


def test_a_clean_table_and_a_table_encoder_without_the_names(tmp_path, caplog):
    data = _tiny("grey carpet tiles")
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    opts = SceneOptions(**OPTS, classes=str(path))
    s = make_scene(TableEncoder(table=_table(data)), opts)
    assert s.absent_lookalikes == []
    write_scene(s, tmp_path / "s.npz", opts)
    assert "absent_lookalikes" not in yaml.safe_load((tmp_path / "s.queries.yaml").read_text())
    # a table encoder that holds only the appearance names still builds the scene
    table = _table(data)
    only = {n: table[n] for c in data["classes"] for n in c["appearance"]}
    with caplog.at_level(logging.INFO, logger="quash_plugins.demo.lookalikes"):
        t = make_scene(TableEncoder(table=only), opts)
    assert np.array_equal(t.map.embeddings, s.map.embeddings)
    assert t.absent_lookalikes == []
    assert any("skipped the check" in r.message for r in caplog.records)


@pytest.fixture(scope="module")
def minilm_encoder():
    pytest.importorskip("sentence_transformers")
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    return MiniLMEncoder(device="cpu")


BENCH = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("a", []),
        ("b", []),
        (str(BENCH / "classes_c.yaml"), []),
        (
            str(BENCH / "classes_d.yaml"),
            [
                ("floor", "terracotta tiles", "aquarium"),
                ("paint can", "tub of wood stain", "bathtub"),
            ],
        ),
        (str(BENCH / "classes_d2.yaml"), []),
    ],
)
def test_the_benchmark_tables(name, expected, minilm_encoder):
    # every lead of tables A, B and C is under LEAD (the largest: 0.165), so make-scene
    # warns about none of them; table D as written holds two, which D2 renames
    cs = class_set(name)
    found = absent_lookalikes(cs.classes, cs.absent, minilm_encoder)
    assert [(x.label, x.appearance, x.absent) for x in found] == expected
