"""benchmarks/bench_ceiling.py: each true object labelled by its mean's best label.

On a noiseless scene whose names all embed as their class's own vector, every object is
nearest its own label: the ceiling is perfect. Give one label another class's vector and
its objects move to that class, which the object accuracy counts exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
from _bench import load_bench
from _eval_table import vec

from quash_plugins.demo.classes import ABSENT, CLASSES
from quash_plugins.demo.scene import SceneOptions, make_scene
from quash_plugins.encoders import TableEncoder

TINY = {
    "rooms": 2,
    "voxel_size": 0.2,
    "room_size": 4.0,
    "extra_objects": 1,
    "noise": 0.0,
    "confusion": 0.0,
    "boundary_blend": 0.0,
    "modality_offset": 0.0,
}


@pytest.fixture(scope="module")
def bc():
    return load_bench("bench_ceiling")


def _encoder(owner: dict[str, str]) -> TableEncoder:
    """Every name embeds as the vector of the class ``owner`` gives it."""
    return TableEncoder(table={name: vec(cls, 64) for name, cls in owner.items()})


def _owners() -> dict[str, str]:
    owner = {}
    for c in CLASSES:
        for name in (c.label, *c.appearance, *c.language):
            owner[name] = c.label
    for label, subs in ABSENT.items():
        for name in (label, *subs):
            owner[name] = label
    for name in ("other", "background", "nothing"):
        owner[name] = name
    return owner


def test_group_scores_readings_by_hand(bc):
    means = np.array([[1.0, 0.0]], np.float32)
    rows = np.array([[0.6, 0.8], [1.0, 0.0], [0.0, 1.0]], np.float32)  # label first
    got = {r: float(bc.group_scores(means, [rows], r)[0, 0]) for r in bc.READINGS}
    assert got["top2"] == pytest.approx((1.0 + 0.6) / 2)
    assert got["top1"] == pytest.approx(1.0)
    assert got["label"] == pytest.approx(0.6)
    mean = rows.mean(axis=0)
    assert got["mean"] == pytest.approx(mean[0] / np.linalg.norm(mean))


def test_a_noiseless_scene_has_a_perfect_ceiling_and_a_moved_label_is_counted(bc, monkeypatch):
    monkeypatch.setitem(bc.GENERATORS, "tiny", TINY)
    owner = _owners()
    rec = bc.one_scene("tiny", 0, _encoder(owner), None)
    for reading in bc.READINGS:
        r = rec["readings"][reading]
        assert r["object_accuracy"] == 1.0, reading
        m = r["margins"]["0.0"]
        assert (m["f1"], m["recall"], m["absence"], m["present_empty"]) == (1.0, 1.0, 1.0, 0)
        assert r["absent_best_margin"] < 0
    # the names offered for chair (its label and sub-classes) now embed as a vector of
    # no class, while its voxels are still built from chair's own: every chair object
    # is read as something else, and no other object changes
    chair = next(c for c in CLASSES if c.label == "chair")
    moved = {**owner, **{n: "elsewhere" for n in (chair.label, *chair.language)}}
    rec2 = bc.one_scene("tiny", 0, _encoder(moved), None)
    scene = make_scene(_encoder(moved), SceneOptions(seed=0, **TINY))
    inst = np.unique(scene.instance_ids, return_inverse=True)[1]
    chair_id = scene.map.label_names.index("chair")
    of_chair = {int(i) for i in np.unique(inst[scene.map.labels == chair_id])}
    assert of_chair  # the tiny scene has chairs
    want = 1 - len(of_chair) / (int(inst.max()) + 1)
    top2 = rec2["readings"]["top2"]
    assert top2["object_accuracy"] == pytest.approx(want)
    assert top2["margins"]["0.0"]["present_empty"] >= 1  # chair gets nothing


@pytest.mark.parametrize(
    "argv,match",
    [
        (["--generators", "nope"], "unknown generator: nope"),
        (["--classes", "{tmp}/nowhere.yaml"], "nowhere.yaml: no such class-table file"),
        (["--seeds", "0-4"], "--seeds '0-4': give comma-separated integers"),
    ],
)
def test_a_refused_run_leaves_no_output_folder(bc, tmp_path, monkeypatch, argv, match):
    out = tmp_path / "ceiling"
    argv = [a.format(tmp=tmp_path) for a in argv]
    monkeypatch.setattr("sys.argv", ["bench_ceiling.py", "--out", str(out), *argv])
    with pytest.raises(SystemExit, match=match):
        bc.main()
    assert not out.exists()
