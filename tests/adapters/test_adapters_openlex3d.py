"""OpenLex3D neutral layout: point_cloud.pcd + embeddings.npy + index.npy."""

from __future__ import annotations

import json

import numpy as np
from _cf_writers import contrast_config, save_openlex3d, text_table, tree_hash

from quash_plugins.adapters import detect_adapter, read_map
from quash_plugins.adapters._rows import IndexedRows
from quash_plugins.cli.main import main
from quash_plugins.core import registry


def test_object_level_index(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-2, 2, size=(40, 3))
    cols = rng.uniform(0, 1, size=(40, 3))
    table = rng.normal(size=(6, 8)).astype(np.float32)
    index = rng.integers(0, 6, size=40)
    index[[3, 9]] = -1
    save_openlex3d(tmp_path / "p", pts, cols, table, index)
    assert detect_adapter(tmp_path / "p") == "openlex3d"
    lmap = registry.create("adapters", "openlex3d").read(tmp_path / "p")
    assert lmap.n == 40 and lmap.dim == 8 and isinstance(lmap.embeddings, IndexedRows)
    np.testing.assert_allclose(lmap.positions, pts.astype(np.float32), atol=1e-6)
    np.testing.assert_array_equal(
        lmap.colors, np.clip(np.rint(cols * 255), 0, 255).astype(np.uint8)
    )
    expected = table[np.clip(index, 0, None)]
    expected[index < 0] = 0
    np.testing.assert_array_equal(lmap.embeddings[0:40], expected)
    np.testing.assert_array_equal(lmap.embeddings[[9, 1, 3]], expected[[9, 1, 3]])
    assert lmap.normalize


def test_a_map_of_objects_exports_as_objects(tmp_path):
    """--format openlex3d keeps a map's objects: the table and the point-to-object index,
    with points of no object on one extra zero row (OpenLex3D reads -1 as the last row)."""
    rng = np.random.default_rng(1)
    pts, cols = rng.uniform(-2, 2, size=(50, 3)), rng.uniform(0, 1, size=(50, 3))
    table = rng.normal(size=(7, 8)).astype(np.float32)
    index = rng.integers(0, 7, size=50)
    index[[0, 11, 49]] = -1
    save_openlex3d(tmp_path / "objects", pts, cols, table, index)
    out = tmp_path / "export"
    args = ["-q", "convert", str(tmp_path / "objects"), str(out), "--format", "openlex3d"]
    assert main(args) == 0
    emb, idx = np.load(out / "embeddings.npy"), np.load(out / "index.npy")
    assert emb.shape == (8, 8) and (idx >= 0).all()
    np.testing.assert_array_equal(emb[:7], table)
    assert not emb[7].any() and (idx[[0, 11, 49]] == 7).all()
    # what OpenLex3D computes, embeddings[index], is the map's rows
    src = read_map(tmp_path / "objects")
    np.testing.assert_array_equal(emb[idx], np.asarray(src.embeddings[0:50]))
    meta = json.loads((out / "quash_export.json").read_text())
    assert meta["dense"] is False and meta["n_points"] == 50 and meta["n_rows"] == 8
    back = read_map(out)
    assert isinstance(back.embeddings, IndexedRows)
    np.testing.assert_array_equal(back.embeddings[0:50], src.embeddings[0:50])


def test_dense_index_uses_memmap(tmp_path):
    rng = np.random.default_rng(1)
    table = rng.normal(size=(25, 4)).astype(np.float16)
    save_openlex3d(tmp_path, rng.normal(size=(25, 3)), None, table, np.arange(25))
    lmap = read_map(tmp_path)
    assert isinstance(lmap.embeddings, np.memmap) and lmap.embeddings.dtype == np.float16
    assert lmap.colors is None and lmap.source["dense"]


def test_cli_query_auto(tmp_path):
    table_path, vecs = text_table(tmp_path, 16)
    table = np.stack([vecs["other"], vecs["chair"], vecs["sofa"]]) * np.array([[2.0], [5.0], [1.0]])
    index = np.array([0, 1, 1, 2, -1, 1, 0, 0])
    save_openlex3d(tmp_path / "p", np.random.default_rng(0).normal(size=(8, 3)), None, table, index)
    before = tree_hash(tmp_path / "p")
    out = tmp_path / "r.npz"
    cfg = contrast_config(tmp_path, table_path)
    assert (
        main(
            [
                "-q",
                "query",
                str(tmp_path / "p"),
                "chair",
                "-c",
                str(cfg),
                "--adapter",
                "auto",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    with np.load(out) as z:
        np.testing.assert_array_equal(z["masks"][0], index == 1)
    assert tree_hash(tmp_path / "p") == before
