"""Ranking metrics (AP, OpenLex3D's inverse rank) and open-vocabulary eval queries.

Expectations come from scikit-learn (AP), from hand-counted ranks (inverse rank) and from
maps built so that the answer is known.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from _eval_table import table_for, vec

from quash_plugins import LatentMap, Quash
from quash_plugins.core.errors import QuashError
from quash_plugins.core.types import FrameInfo
from quash_plugins.encoders import TableEncoder
from quash_plugins.evaluation.ranking import average_precision, inverse_rank, label_segments
from quash_plugins.evaluation.report import evaluate, load_query_file, parse_queries

TAX = {"bed": ["bunk bed", "cot"], "sofa": ["futon", "settee"], "chair": ["armchair"]}


def test_average_precision_matches_sklearn_with_ties():
    from sklearn.metrics import average_precision_score

    rng = np.random.default_rng(0)
    s = rng.normal(size=500).round(1)  # many ties
    t = rng.random(500) < 0.2
    assert average_precision(s, t) == pytest.approx(average_precision_score(t, s))
    v = rng.random(500) < 0.7
    assert average_precision(s, t, v) == pytest.approx(average_precision_score(t[v], s[v]))
    assert average_precision(s, np.zeros(500, bool)) is None


def test_inverse_rank_follows_openlex3d():
    # objects by mean score: 0 (gt) rank 1, 2 rank 2, 3 (gt) rank 3; OpenLex3D subtracts
    # the ground-truth objects found before: ranks 1 and 3 - 1 = 2 -> (1 + 1/2) / 2
    scores = np.array([0.9, 0.9, 0.1, 0.1, 0.8, 0.8, 0.2, 0.2])
    segments = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    truth = np.array([1, 1, 0, 0, 0, 0, 1, 1], bool)
    assert inverse_rank(scores, segments, truth) == pytest.approx(0.75)
    # a top-k cut at 2 drops the object at raw rank 3
    assert inverse_rank(scores, segments, truth, max_rank=2) == pytest.approx(0.5)
    # the two ground-truth objects ranked first and second: each scores 1
    top2 = np.array([1, 1, 0, 0, 1, 1, 0, 0], bool)
    assert inverse_rank(scores, segments, top2) == pytest.approx(1.0)
    assert inverse_rank(scores, segments, np.zeros(8, bool)) is None


def test_inverse_rank_hand_example_from_docs():
    # docs/evaluation.md: ground-truth objects at ranks 2, 4 and 5 count as 2, 3 and 3
    # (minus the 0, 1 and 2 objects found before them)
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.5])
    truth = np.array([0, 1, 0, 1, 1], bool)
    expected = (1 / 2 + 1 / 3 + 1 / 3) / 3
    assert inverse_rank(scores, np.arange(5), truth) == pytest.approx(expected)
    assert round(expected, 3) == 0.389
    # segments of several items rank by their mean score; ties keep segment order
    seg = np.repeat(np.arange(5), 3)
    jitter = np.tile([-0.01, 0.0, 0.01], 5)
    assert inverse_rank(np.repeat(scores, 3) + jitter, seg, np.repeat(truth, 3)) == (
        pytest.approx(expected)
    )
    # a query whose ground truth is one object ranked first: 1; pooled with the query
    # above as OpenLex3D's summary does, (1 + 3 * expected) / 4, not the mean of queries
    one = inverse_rank(scores, np.arange(5), np.array([1, 0, 0, 0, 0], bool))
    assert one == 1.0
    assert (one + 3 * expected) / 4 != pytest.approx((one + expected) / 2)


def test_label_segments_for_voxels_points_and_pixels():
    grid = np.array([[0, 0, 0], [0, 0, 1], [5, 5, 5], [1, 1, 1]])
    labels = np.array([1, 1, 1, -1])
    m = LatentMap(np.ones((4, 2), np.float32), kind="voxels", grid_index=grid, voxel_size=0.1)
    assert label_segments(labels, m).tolist() == [0, 0, 1, -1]
    pts = np.array([[0, 0, 0], [0.05, 0, 0], [3, 3, 3]], np.float32)
    p = LatentMap(np.ones((3, 2), np.float32), kind="points", positions=pts, voxel_size=0.1)
    assert label_segments(np.array([0, 0, 0]), p).tolist() == [0, 0, 1]
    # two 2x3 frames; label 0 on two separate pixels of frame 0 and one of frame 1
    frames = [FrameInfo("a", 2, 3, 0), FrameInfo("b", 2, 3, 6)]
    px = LatentMap(np.ones((12, 2), np.float32), kind="pixels", frames=frames)
    lab = np.full(12, 1)
    lab[[0, 2, 7]] = 0
    seg = label_segments(lab, px)
    assert len({seg[0], seg[2], seg[7]}) == 3  # not 8-connected, or another frame
    bare = LatentMap(np.ones((3, 2), np.float32))
    assert label_segments(np.array([0, 0, 1]), bare) is None


def test_parse_queries_and_query_files(tmp_path):
    assert parse_queries(["chair", "bunk bed=bed", " somewhere  to sleep = bed "]) == {
        "chair": "chair",
        "bunk bed": "bed",
        "somewhere to sleep": "bed",
    }
    assert parse_queries({"futon": "sofa"}) == {"futon": "sofa"}
    with pytest.raises(QuashError, match="TEXT=LABEL"):
        parse_queries(["bunk bed="])
    f = tmp_path / "q.yaml"
    f.write_text("present:\n  bunk bed: bed\n  sofa: sofa\nabsent: [an elephant]\n")
    assert load_query_file(f) == ({"bunk bed": "bed", "sofa": "sofa"}, ["an elephant"])
    f.write_text("present: [chair, bed]\nabsent: [piano]\nroom_types: [kitchen]\n")
    assert load_query_file(f) == ({"chair": "chair", "bed": "bed"}, ["piano"])
    # a number is refused as a label index, as in a mapping; a quoted one is a name
    f.write_text("- 3\n")
    with pytest.raises(QuashError, match=r"item 3 \(int\) is not text"):
        load_query_file(f)
    f.write_text('- "3"\n')
    assert load_query_file(f) == ({"3": "3"}, [])
    f.write_text("just text\n")
    with pytest.raises(QuashError, match="query file"):
        load_query_file(f)


def _bed_sofa_map():
    """A 27-voxel bed block and a 27-voxel sofa block apart; hashed 32-d text space."""
    rng = np.random.default_rng(0)
    grid, rows, labels = [], [], []
    for li, (name, x0) in enumerate((("bed", 0), ("sofa", 10))):
        for x in range(3):
            for y in range(3):
                for z in range(3):
                    grid.append((x0 + x, y, z))
                    rows.append(np.asarray(vec(name)) + 0.2 * rng.standard_normal(32))
                    labels.append(li)
    E = np.asarray(rows, np.float32)
    E /= np.linalg.norm(E, axis=1, keepdims=True)
    return LatentMap(
        E,
        kind="voxels",
        grid_index=np.asarray(grid),
        voxel_size=0.1,
        labels=np.asarray(labels),
        label_names=["bed", "sofa"],
    )


def _peer(name="peer"):
    from quash_plugins.core import registry

    names = {n for k, v in TAX.items() for n in (k, *v)} | {"other", "background", "nothing"}
    enc = TableEncoder(table=table_for(names | {"a futon"}))
    return Quash(
        enc,
        registry.create("heuristics", "label-list", taxonomy=TAX),
        registry.create("classifiers", "label-argmax"),
        negatives=["other"],
        instances=False,
        name=name,
    )


def test_eval_scores_open_vocabulary_queries_against_their_label():
    m = _bed_sofa_map()
    rep = evaluate(m, [_peer()], queries=["bunk bed=bed", "a futon=sofa"], absent=["chair"])
    c = rep.configs[0]
    pq = c["per_query"]
    assert list(pq) == ["bunk bed", "a futon"]
    assert pq["bunk bed"]["label"] == "bed" and pq["bunk bed"]["n_true"] == 27
    assert pq["a futon"]["label"] == "sofa" and pq["a futon"]["n_true"] == 27
    # the sub-class resolves to its label, so the peer finds the whole block
    assert pq["bunk bed"]["recall"] == 1.0 and pq["bunk bed"]["ap"] == pytest.approx(1.0)
    assert pq["bunk bed"]["inv_rank"] == pytest.approx(1.0)
    assert set(c["mean"]) >= {"precision", "recall", "f1", "iou", "ap", "inv_rank"}
    assert c["given"] == "the label list (the taxonomy given in memory)"
    assert c["absence"]["present_empty"] == 0
    # a query whose label is a near miss of the map's is refused; a label that the map
    # does not name (listed absent or not) makes an absence query
    with pytest.raises(QuashError, match=r"Query 'a cot': its label 'bedd' is not a label"):
        evaluate(m, [_peer()], queries=["bunk bed=bed", "a cot=bedd"])
    rep1 = evaluate(m, [_peer()], queries=["bunk bed=bed", "armchair=chair"])
    assert rep1.queries == ["bunk bed"] and rep1.absent == ["armchair"]
    rep2 = evaluate(m, [_peer()], queries=["bunk bed=bed", "armchair=chair"], absent=["chair"])
    assert rep2.queries == ["bunk bed"] and rep2.absent == ["armchair", "chair"]


def test_cli_eval_takes_text_label_queries_and_a_query_file(tmp_path, capsys, monkeypatch):
    from quash_plugins.adapters import write_npz_map

    monkeypatch.setenv("COLUMNS", "200")  # headers whole on one line
    from quash_plugins.cli.main import main

    names = {n for k, v in TAX.items() for n in (k, *v)} | {"other", "background", "nothing"}
    np.savez(
        tmp_path / "text.npz",
        texts=np.asarray(sorted(names)),
        embeddings=np.asarray([vec(n) for n in sorted(names)], np.float32),
    )
    write_npz_map(_bed_sofa_map(), tmp_path / "map.npz")
    (tmp_path / "peer.yaml").write_text(
        "name: peer\nencoder: {name: table, file: text.npz}\n"
        "heuristic: {name: label-list, file: tax.yaml}\nnegatives: [other]\n"
        "classifier: label-argmax\ninstances: false\ncache: false\n"
    )
    (tmp_path / "tax.yaml").write_text(json.dumps(TAX))
    out = tmp_path / "r.json"
    args = ["eval", str(tmp_path / "map.npz"), "-c", str(tmp_path / "peer.yaml")]
    assert main([*args, "--queries", "bunk bed=bed,settee=sofa", "--json", str(out)]) == 0
    data = json.loads(out.read_text())["configs"][0]
    assert {q: v["label"] for q, v in data["per_query"].items()} == {
        "bunk bed": "bed",
        "settee": "sofa",
    }
    assert data["given"] == "the label list (tax.yaml)"
    printed = capsys.readouterr().out
    assert "the label list (tax.yaml)" in printed and "inv. rank" in printed
    qf = tmp_path / "q.yaml"
    qf.write_text("present: {cot: bed}\nabsent: [armchair]\n")
    assert main([*args, "--queries-file", str(qf), "--json", str(out), "--force"]) == 0
    data = json.loads(out.read_text())["configs"][0]
    assert list(data["per_query"]) == ["cot"]
    assert list(data["absence"]["per_query"]) == ["armchair"]
