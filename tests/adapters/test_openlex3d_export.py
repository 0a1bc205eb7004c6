"""OpenLex3D interop: ``quash convert --format openlex3d`` and ``quash query --format openlex3d``."""

from __future__ import annotations

import json
import logging
import re
import warnings
from pathlib import Path

import numpy as np
import pytest
from _cf_writers import cf_arrays, contrast_config, save_pointclouds, text_table, tree_hash

from quash_plugins.adapters import read_map, write_pcd
from quash_plugins.cli.main import main
from quash_plugins.core.errors import EmptyMapWarning, UsageError

o3d = pytest.importorskip("open3d")
DOC = Path(__file__).resolve().parents[2] / "docs" / "adapters.md"


def cf_map(tmp_path, n=60, d=16, vecs=None, chair_rows=()):
    arrays = cf_arrays(n=n, d=d, vecs=vecs, chair_rows=chair_rows)
    save_pointclouds(tmp_path / "saved-map", **arrays)
    return tmp_path / "saved-map", arrays


def test_pcd_writer_reads_back_with_open3d(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3)) * 10
    cols = rng.integers(0, 256, size=(50, 3), dtype=np.uint8)
    write_pcd(tmp_path / "c.pcd", pts, cols)
    legacy = o3d.io.read_point_cloud(str(tmp_path / "c.pcd"))
    np.testing.assert_array_equal(np.asarray(legacy.points), pts.astype(np.float32))
    np.testing.assert_array_equal(np.rint(np.asarray(legacy.colors) * 255), cols)
    tensor = o3d.t.io.read_point_cloud(str(tmp_path / "c.pcd"))  # what OpenLex3D calls
    np.testing.assert_array_equal(tensor.point.positions.numpy(), pts.astype(np.float32))
    np.testing.assert_array_equal(tensor.point.colors.numpy(), cols)
    write_pcd(tmp_path / "x.pcd", pts[:4], None)
    back = o3d.io.read_point_cloud(str(tmp_path / "x.pcd"))
    assert len(back.points) == 4 and not back.has_colors()
    header = (tmp_path / "c.pcd").read_bytes().split(b"DATA binary\n")[0].decode()
    assert "FIELDS x y z rgb" in header and "POINTS 50" in header


def test_convert_writes_the_triple(tmp_path, capsys):
    src, arrays = cf_map(tmp_path)
    before = tree_hash(src)
    out = tmp_path / "preds" / "quash" / "replica" / "room0"
    assert main(["convert", str(src), str(out), "--format", "openlex3d"]) == 0
    assert tree_hash(src) == before
    emb = np.load(out / "embeddings.npy")
    assert emb.dtype == np.float32
    np.testing.assert_array_equal(emb, arrays["pc_embeddings"].astype(np.float32))
    index = np.load(out / "index.npy")
    np.testing.assert_array_equal(index, np.arange(60))
    cloud = o3d.t.io.read_point_cloud(str(out / "point_cloud.pcd"))
    np.testing.assert_array_equal(cloud.point.positions.numpy(), arrays["pc_points"])
    np.testing.assert_array_equal(
        cloud.point.colors.numpy(), np.rint(arrays["pc_colors"]).astype(np.uint8)
    )
    meta = json.loads((out / "quash_export.json").read_text())
    assert meta["n_points"] == 60 and meta["source"]["adapter"] == "conceptfusion"
    back = read_map(out)  # our openlex3d reader: the same map
    assert back.source["adapter"] == "openlex3d" and back.source["dense"]
    np.testing.assert_array_equal(np.asarray(back.embeddings), emb)
    # a second export replaces the first; a folder of the user's is never replaced
    assert main(["convert", str(src), str(out), "--format", "openlex3d"]) == 0
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert main(["convert", str(src), str(mine), "--format", "openlex3d"]) == 2
    assert (mine / "notes.txt").read_text() == "keep" and len(list(mine.iterdir())) == 1
    assert "not a previous OpenLex3D export" in capsys.readouterr().err
    assert main(["convert", str(src), str(src / "inside"), "--format", "openlex3d"]) == 2
    assert main(["convert", str(src), str(tmp_path / "x.npz"), "--format", "openlex3d"]) == 2
    assert not list(tmp_path.glob(".*tmp*"))


def test_convert_pixel_maps_and_empty_maps(tmp_path):
    from _cf_writers import save_feat_pt

    from quash_plugins.adapters import convert_map

    save_feat_pt(tmp_path / "feat", "a", np.ones((2, 3, 4), np.float16))
    with pytest.raises(UsageError, match="no positions"):
        convert_map(tmp_path / "feat", tmp_path / "px", "image-features", format="openlex3d")
    src, _ = cf_map(tmp_path / "e", n=0)
    out = convert_map(src, tmp_path / "empty", format="openlex3d")
    assert np.load(out / "embeddings.npy").shape == (0, 16)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # open3d has no words for an empty cloud
        back = read_map(out)
    assert back.n == 0


def test_query_writes_per_query_scores_and_masks(tmp_path, capsys):
    table, vecs = text_table(tmp_path, dim=16)
    src, _ = cf_map(tmp_path, n=80, vecs=vecs, chair_rows=range(10, 30))
    export = tmp_path / "preds" / "room0"
    assert main(["-q", "convert", str(src), str(export), "--format", "openlex3d"]) == 0
    cfg = contrast_config(tmp_path, table)
    npz = tmp_path / "r.npz"
    assert main(["query", str(export), "chair", "sofa", "-c", str(cfg), "--out", str(npz)]) == 0
    out = tmp_path / "results" / "room0"
    args = ["query", str(export), "chair", "sofa", "-c", str(cfg), "--out", str(out)]
    assert main([*args, "--format", "openlex3d"]) == 0
    with np.load(npz) as z:
        masks, scores, display = z["masks"], z["scores"], z["display_scores"]
    got_masks = np.load(out / "query_masks.npy")
    got_scores = np.load(out / "query_scores.npy")
    assert got_masks.shape == (80, 2) and got_masks.dtype == bool
    np.testing.assert_array_equal(got_masks, masks.T)
    np.testing.assert_array_equal(np.load(out / "query_scores_raw.npy"), scores.T)
    np.testing.assert_array_equal(got_scores, display.T)
    np.testing.assert_array_equal(got_scores > 0.5, got_masks)  # OpenLex3D's 0.5 cut
    chairs = [r for r in range(10, 30) if r % 5]  # cf_arrays zeroes every fifth row
    np.testing.assert_array_equal(np.flatnonzero(got_masks[:, 0]), chairs)
    meta = json.loads((out / "queries.json").read_text())
    assert [q["query_text"] for q in meta["queries"]] == ["chair", "sofa"]
    assert meta["queries"][0]["column"] == 0 and meta["n_items"] == 80
    assert meta["queries"][0]["matched"] == len(chairs)
    # rows follow the exported embeddings.npy: top-ranked rows are chair rows
    top = np.argsort(-np.load(out / "query_scores_raw.npy")[:, 0], kind="stable")[:10]
    assert set(top) <= set(chairs)
    assert main([*args, "--format", "openlex3d"]) == 0  # a previous result is replaced
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "a.txt").write_text("keep")
    mine_args = ["query", str(export), "chair", "-c", str(cfg), "--out", str(mine)]
    assert main([*mine_args, "--format", "openlex3d"]) == 2
    assert (mine / "a.txt").exists()
    inside = ["query", str(export), "chair", "-c", str(cfg), "--out", str(export / "q")]
    assert main([*inside, "--format", "openlex3d"]) == 2


def test_query_on_an_empty_map(tmp_path):
    table, _ = text_table(tmp_path, dim=16)
    src, _ = cf_map(tmp_path, n=0)
    out = tmp_path / "q"
    with pytest.warns(EmptyMapWarning):
        rc = main(["query", str(src), "chair", "-c", str(contrast_config(tmp_path, table)),
                   "--out", str(out), "--format", "openlex3d"])  # fmt: skip
    assert rc == 0 and np.load(out / "query_masks.npy").shape == (0, 1)


def test_docs_snippet_runs(tmp_path, monkeypatch, capsys):
    table, vecs = text_table(tmp_path, dim=16)
    src, _ = cf_map(tmp_path, n=40, vecs=vecs, chair_rows=range(5))
    cfg = contrast_config(tmp_path, table)
    monkeypatch.chdir(tmp_path)
    args = ["query", str(src), "chair", "-c", str(cfg), "--out", "results/office0"]
    assert main([*args, "--format", "openlex3d"]) == 0
    section = DOC.read_text().split("### Writing OpenLex3D's layout")[1].split("### Pickles")[0]
    [code] = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    exec(compile(code, str(DOC), "exec"), {})
    assert "chair [" in capsys.readouterr().out


def test_convert_keeps_the_encoder_record(minilm_scene, tmp_path):
    """A map made by make-scene records its encoder; the OpenLex3D export keeps it in
    quash_export.json and the adapter reads it back."""
    out = tmp_path / "ol3d"
    assert main(["-q", "convert", str(minilm_scene), str(out), "--format", "openlex3d"]) == 0
    src, back = read_map(minilm_scene), read_map(out, adapter="openlex3d")
    assert src.source["encoder"] == "minilm"
    for key in ("encoder", "encoder_fingerprint"):
        assert back.source[key] == src.source[key]
    (out / "quash_export.json").write_text("{not json", encoding="utf-8")
    assert "encoder" not in read_map(out, adapter="openlex3d").source


def test_query_of_a_pixel_map_refuses_openlex3d_output_before_any_query(
    tmp_path, capsys, monkeypatch
):
    """A pixel map has no OpenLex3D export (convert refuses it), so --format openlex3d
    results cannot be aligned with one: refused as convert does, before any work."""
    from _cf_writers import save_feat_pt

    from quash_plugins.engine.pipeline import Quash

    table, vecs = text_table(tmp_path, dim=16)
    feat = np.stack([np.stack([vecs["chair"]] * 4)] * 3).astype(np.float16)  # (3, 4, 16)
    save_feat_pt(tmp_path / "feat", "a", feat)
    cfg = contrast_config(tmp_path, table)
    out = tmp_path / "results"
    args = ["query", str(tmp_path / "feat"), "chair", "-c", str(cfg), "--out", str(out)]

    def no_query(*a, **k):
        raise AssertionError("a query ran before the refusal")

    monkeypatch.setattr(Quash, "query_many", no_query)
    assert main([*args, "--format", "openlex3d"]) == 2
    err = capsys.readouterr().err
    assert "has no positions (a pixel map?)" in err and "point_cloud.pcd" in err
    assert "--out RESULT.npz" in err
    assert not out.exists() and not list(tmp_path.glob(".*tmp*"))
    # convert says the same of the same map
    assert (
        main(["convert", str(tmp_path / "feat"), str(tmp_path / "x"), "--format", "openlex3d"]) == 2
    )
    assert "has no positions (a pixel map?)" in capsys.readouterr().err


def test_export_records_the_up_axis_and_reads_it_back(tmp_path):
    """A cloud in a y-up frame (ConceptFusion records no axis) keeps the axis that
    ``--up`` gave through the export: ``quash_export.json``'s ``up``, read back."""
    from quash_plugins.core.errors import MapFormatError

    src, _ = cf_map(tmp_path)
    out = tmp_path / "preds"
    assert main(["-q", "convert", str(src), str(out), "--format", "openlex3d", "--up", "+y"]) == 0
    assert json.loads((out / "quash_export.json").read_text())["up"] == "+y"
    assert read_map(out).source["up"] == "+y"
    assert main(["-q", "convert", str(out), str(tmp_path / "m.npz")]) == 0
    assert read_map(tmp_path / "m.npz").source["up"] == "+y"  # and on into the NPZ
    assert main(["-q", "convert", str(src), str(tmp_path / "z"), "--format", "openlex3d"]) == 0
    assert "up" not in json.loads((tmp_path / "z" / "quash_export.json").read_text())
    assert "up" not in read_map(tmp_path / "z").source  # no axis recorded: +z assumed
    meta = json.loads((out / "quash_export.json").read_text())
    (out / "quash_export.json").write_text(json.dumps({**meta, "up": "y"}), encoding="utf-8")
    with pytest.raises(MapFormatError, match=r"quash_export\.json.*'up'.*'y'.*\+y"):
        read_map(out)


def test_a_cut_short_export_record_says_the_up_axis_is_lost_too(tmp_path, caplog):
    """A ``quash_export.json`` cut short loses the up axis it records as well as the
    encoder record; the warning said only the encoder, and the y-up map was read as z-up
    with nothing said of its axis."""
    src, _ = cf_map(tmp_path)
    out = tmp_path / "preds"
    assert main(["-q", "convert", str(src), str(out), "--format", "openlex3d", "--up", "+y"]) == 0
    marker = out / "quash_export.json"
    marker.write_bytes(marker.read_bytes()[: len(marker.read_bytes()) // 2])
    quash_log = logging.getLogger("quash_plugins")  # main() stops it propagating
    quash_log.addHandler(caplog.handler)
    try:
        with caplog.at_level(logging.WARNING):
            lmap = read_map(out)
    finally:
        quash_log.removeHandler(caplog.handler)
    assert "up" not in lmap.source
    said = [r.getMessage() for r in caplog.records if "quash_export.json" in r.getMessage()]
    assert len(said) == 1 and "up axis" in said[0] and "--up" in said[0], said
