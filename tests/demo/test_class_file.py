"""Class-table files: ``quash make-scene --classes FILE.yaml`` and ``--show-classes``."""

from __future__ import annotations

import copy
import dataclasses
import hashlib

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins.cli.main import main
from quash_plugins.core.errors import ConfigError
from quash_plugins.demo.class_file import class_table_data, load_class_table, parse_class_table
from quash_plugins.demo.scene import SceneOptions, class_set, make_scene, write_scene
from quash_plugins.encoders import TableEncoder

OPTS = dict(rooms=2, voxel_size=0.25, room_size=4.0, extra_objects=1)


def _tiny() -> dict:
    """A small valid table of our own: an office and a store room."""
    c = [
        ("floor", ["grey carpet tiles"], ["ground"], "structure"),
        ("wall", ["painted plaster"], ["partition"], "structure"),
        ("ceiling", ["ceiling grid"], ["roof"], "structure"),
        ("door", ["oak door leaf"], ["doorway"], "wall"),
        ("window", ["glazed pane"], ["casement"], "wall"),
        ("desk", ["writing surface with drawers"], ["workstation"], "floor"),
        ("printer", ["paper tray machine"], ["copier"], "top"),
        ("locker", ["tall steel compartment"], ["cubby"], "floor"),
    ]
    return {
        "name": "tiny",
        "classes": [
            {"label": a, "appearance": b, "language": d, "color": [10 * i, 0, 0], "place": p}
            for i, (a, b, d, p) in enumerate(c)
        ],
        "absent": {"piano": ["grand piano"]},
        "absent_free_text": ["an elephant"],
        "supports": ["desk"],
        "room_types": {"office": ["desk", "printer"], "store": ["locker"]},
        "free_text": {"printer": "where my pages come out"},
        "wall_bottom": ["door"],
        "wall_top": [],
    }


def _names(data: dict) -> set[str]:
    return {n for c in data["classes"] for n in c["appearance"]}


@pytest.mark.parametrize("name", ["a", "b"])
def test_shipped_tables_round_trip(name):
    cs = class_set(name)
    assert parse_class_table(class_table_data(cs), f"{name}.yaml") == cs


def test_a_file_builds_the_same_scene_as_the_table(tmp_path):
    data = class_table_data(class_set("a"))
    path = tmp_path / "mine.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    enc = TableEncoder(table=table_for(_names(data)))
    a = make_scene(enc, SceneOptions(**OPTS))
    b = make_scene(enc, SceneOptions(**OPTS, classes=str(path)))
    assert np.array_equal(a.map.embeddings, b.map.embeddings)
    assert np.array_equal(a.map.labels, b.map.labels)
    assert a.taxonomy == b.taxonomy


def test_a_table_of_our_own_builds_its_scene(tmp_path):
    data = _tiny()
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    enc = TableEncoder(table=table_for(_names(data)))
    s = make_scene(enc, SceneOptions(**OPTS, classes=str(path)))
    assert s.map.label_names == [c["label"] for c in data["classes"]]
    present = {s.map.label_names[i] for i in np.unique(s.map.labels)}
    assert {"desk", "printer", "locker", "door", "window"} <= present
    # the printer stands on the desk: its lowest voxel sits on the desk's top
    names = s.map.label_names
    pz = s.map.positions[s.map.labels == names.index("printer"), 2].min()
    dz = s.map.positions[s.map.labels == names.index("desk"), 2].max()
    assert pz == pytest.approx(dz + OPTS["voxel_size"], abs=1e-5)
    assert s.taxonomy["printer"] == ["copier"] and s.taxonomy["piano"] == ["grand piano"]
    assert s.open_present.get("where my pages come out") == "printer"
    assert "grand piano" in s.open_absent
    # the queries file records which content built the scene
    write_scene(s, tmp_path / "s.npz", SceneOptions(**OPTS, classes=str(path)))
    info = yaml.safe_load((tmp_path / "s.queries.yaml").read_text())
    assert info["options"]["classes"] == str(path)
    assert info["class_table_sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()


def _broken(edit) -> dict:
    data = copy.deepcopy(_tiny())
    edit(data)
    return data


@pytest.mark.parametrize(
    ("edit", "field", "words"),
    [
        (lambda d: d.pop("supports"), "supports", "missing"),
        (lambda d: d.update(colour=[1, 2, 3]), "colour", "unknown key"),
        (lambda d: d["classes"][5].update(place="shelf"), "classes[5] (desk).place", "one of"),
        (lambda d: d["classes"][5].update(color=[1, 2]), "classes[5] (desk).color", "0-255"),
        (lambda d: d["classes"][5].update(size=[1, 0, 1]), "classes[5] (desk).size", "metres"),
        (lambda d: d["classes"].pop(0), "classes", "'floor'"),
        (lambda d: d["classes"][3].update(place="floor"), "classes (door).place", "wall"),
        (lambda d: d["room_types"]["office"].append("sofa"), "room_types.office", "not a class"),
        (
            lambda d: d["room_types"]["office"].append("printers"),
            "room_types.office",
            "not a class label; did you mean 'printer'?",
        ),
        (lambda d: d.update(supports=["printer"]), "supports", "must be floor"),
        (
            lambda d: d["room_types"].update(office=["printer"]),
            "room_types.office",
            "has none",
        ),
        (lambda d: d["room_types"].update(office=["wall"]), "room_types.office", "structure"),
        (lambda d: d["absent"].update(desk=["bureau"]), "absent.desk", "is a class"),
        (lambda d: d["absent"].update(piano=[]), "absent.piano", "give at least one"),
        (
            lambda d: d["classes"][6].update(appearance=["copier"]),
            "classes (printer).appearance",
            "also a label or language name",
        ),
        (lambda d: d["classes"][6].update(label="desk"), "classes", "twice"),
        # a name under two labels: its query would have two answers
        (
            lambda d: d["classes"][7].update(language=["cubby", "Workstation"]),
            "classes[7] (locker).language",
            "'Workstation' is also a name of 'desk'",
        ),
        (
            lambda d: (
                d["classes"][7].update(label="Desk"),
                d["room_types"].update(store=["Desk"]),
            ),
            "classes[7] (Desk).label",
            "also a name of 'desk'",
        ),
        (lambda d: d["absent"].update(piano=["copier"]), "absent.piano", "name of 'printer'"),
        (
            lambda d: d.update(absent_free_text=["an elephant", "a copier"]),
            "absent_free_text",
            "'a copier' names 'printer'",
        ),
        (lambda d: d["free_text"].update(sofa="x"), "free_text.sofa", "not a class label"),
        (lambda d: d.update(wall_top=["desk"]), "wall_top", "must be wall"),
        (lambda d: d["classes"][6].update(appearance="paper tray"), "appearance", "list"),
    ],
)
def test_bad_tables_name_the_field_and_the_fix(edit, field, words):
    with pytest.raises(ConfigError) as err:
        parse_class_table(_broken(edit), "mine.yaml")
    msg = str(err.value)
    assert msg.startswith("mine.yaml: ") and field in msg and words in msg, msg


def test_optional_keys_default_to_the_labels_the_table_has():
    data = _tiny()
    del data["wall_bottom"], data["wall_top"], data["name"]
    cs = parse_class_table(data, "dir/tiny.yaml")
    # table A's defaults (door, radiator; curtain) without the labels this table lacks
    assert cs.wall_bottom == ("door",) and cs.wall_top == ()
    assert cs.name == "tiny" and cs.absent_free_text_open == ("an elephant",)


def test_missing_file_and_bad_option(tmp_path):
    with pytest.raises(ConfigError, match="no such class-table file.*--show-classes"):
        load_class_table(tmp_path / "none.yaml")
    with pytest.raises(ConfigError, match="one of a, b or a class-table YAML file"):
        SceneOptions(classes="c").validate()


def test_cli_show_classes_writes_a_file_make_scene_reads(tmp_path, capsys):
    assert main(["make-scene", "--show-classes", "--classes", "b"]) == 0
    text = capsys.readouterr().out
    assert text.startswith("# quash make-scene class table 'b'")
    path = tmp_path / "b.yaml"
    path.write_text(text, encoding="utf-8")
    loaded = load_class_table(path)
    assert loaded.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    assert dataclasses.replace(loaded, sha256=None) == class_set("b")
    # no OUT and no --show-classes: a usage error, no traceback
    assert main(["make-scene"]) == 2
    assert "give OUT.npz" in capsys.readouterr().err


def test_cli_make_scene_with_a_bad_file_names_it(tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(_broken(lambda d: d.pop("room_types"))), encoding="utf-8")
    rc = main(["make-scene", str(tmp_path / "s.npz"), "--classes", str(path), "--no-cache"])
    err = capsys.readouterr().err
    assert rc != 0 and f"{path}: room_types: missing" in err
    assert not (tmp_path / "s.npz").exists()


@pytest.mark.parametrize("beside", ["taxonomy", "queries", "open-queries"])
def test_cli_make_scene_never_writes_over_its_class_file(tmp_path, capsys, beside):
    """A class file named like one of the scene's outputs is an input: --force or not,
    make-scene refuses before any work instead of replacing the table with its output."""
    path = tmp_path / f"s.{beside}.yaml"
    path.write_text(yaml.safe_dump(_tiny(), sort_keys=False), encoding="utf-8")
    before = path.read_bytes()
    for force in ([], ["--force"]):
        out = ["make-scene", str(tmp_path / "s.npz"), "--classes", str(path), *force]
        assert main([*out, "--no-cache"]) == 2
        assert "is the input" in capsys.readouterr().err
    assert path.read_bytes() == before and not (tmp_path / "s.npz").exists()


def test_an_object_longer_than_the_room_is_cut_to_fit_inside_its_walls(tmp_path):
    """A car of 6 m in a 4 m room: the layout ran past the last room's end (an IndexError)
    or through the wall into the next room; now the object stays inside its own room."""
    data = _tiny()
    data["classes"][7]["size"] = [6.0, 6.0, 1.0]  # the locker, in the second room
    data["classes"][5]["size"] = [6.0, 0.7, 0.75]  # the desk, in the first
    path = tmp_path / "big.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    enc = TableEncoder(table=table_for(_names(data)))
    s = make_scene(enc, SceneOptions(**OPTS, classes=str(path)))
    n_room = round(OPTS["room_size"] / OPTS["voxel_size"])
    for label, room in (("locker", 1), ("desk", 0)):
        cells = s.map.grid_index[s.map.labels == s.map.label_names.index(label)]
        assert len(cells), label
        x, y = cells[:, 0] - room * n_room, cells[:, 1]
        assert x.min() > 0 and x.max() < n_room and y.min() > 0 and y.max() < n_room, label
