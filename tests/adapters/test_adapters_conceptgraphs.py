"""ConceptGraphs ``*.pkl.gz`` maps (``openlex3d`` with ``allow_pickle=True``): objects
and background objects, saved the way ConceptGraphs saves them."""

from __future__ import annotations

import gzip
import logging
import pickle

import numpy as np
import pytest

from quash_plugins.adapters import read_map
from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError


def _object(rng, n_points, dim, color):
    """One entry of ``MapObjectList.to_serializable()`` (ConceptGraphs' slam_classes):
    the same fields for objects and background objects."""
    return {
        "clip_ft": rng.normal(size=dim).astype(np.float32),
        "text_ft": rng.normal(size=dim).astype(np.float32),
        "pcd_np": rng.uniform(-2, 2, size=(n_points, 3)),
        "bbox_np": rng.uniform(-2, 2, size=(8, 3)),
        "pcd_color_np": np.tile(np.asarray(color, np.float64), (n_points, 1)),
        "class_name": ["thing"],
    }


def save_conceptgraphs(path, objects, bg_objects):
    """``gzip`` + ``pickle`` of the dict ConceptGraphs' mapping saves (``save_pcd``)."""
    results = {
        "objects": objects,
        "bg_objects": bg_objects,
        "cfg": {"use_bg": bg_objects is not None},
        "class_names": ["thing", "wall", "floor"],
        "class_colors": {},
    }
    with gzip.open(path, "wb") as f:
        pickle.dump(results, f)
    return path


@pytest.fixture
def cg_map(tmp_path):
    rng = np.random.default_rng(0)
    objects = [_object(rng, 5, 8, (1.0, 0.0, 0.0)), _object(rng, 3, 8, (0.0, 1.0, 0.0))]
    bg = [_object(rng, 7, 8, (0.0, 0.0, 1.0)), _object(rng, 4, 8, (1.0, 1.0, 1.0))]
    path = save_conceptgraphs(tmp_path / "full_pcd_ram_withbg.pkl.gz", objects, bg)
    return path, objects, bg


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def test_background_objects_are_read_after_the_objects(cg_map):
    path, objects, bg = cg_map
    lmap = read_map(path, allow_pickle=True)
    everything = objects + bg
    assert lmap.n == sum(len(o["pcd_np"]) for o in everything) == 19
    np.testing.assert_allclose(
        lmap.positions, np.concatenate([o["pcd_np"] for o in everything]).astype(np.float32)
    )
    # every point carries its own object's feature, background objects included
    expected = np.concatenate([np.tile(o["clip_ft"], (len(o["pcd_np"]), 1)) for o in everything])
    np.testing.assert_allclose(np.asarray(lmap.embeddings), expected)
    table = lmap.embeddings.table
    np.testing.assert_allclose(table[len(objects) :], np.stack([o["clip_ft"] for o in bg]))
    # colours of the background points too (0-1 in the file)
    np.testing.assert_array_equal(lmap.colors[8:15], np.tile([0, 0, 255], (7, 1)))
    assert lmap.source["objects"] == 2 and lmap.source["background_objects"] == 2
    # a query can find the wall: its rows are real, not zeros
    block = np.concatenate([b for _, _, b in lmap.iter_chunks(6)])
    np.testing.assert_allclose(block[8:15], np.tile(_unit(bg[0]["clip_ft"]), (7, 1)), atol=1e-6)


def test_background_false_leaves_them_out_and_says_how_many(cg_map, caplog):
    path, objects, bg = cg_map
    adapter = registry.create("adapters", "openlex3d", allow_pickle=True, background=False)
    with caplog.at_level(logging.INFO, logger="quash_plugins"):
        lmap = adapter.read(path)
    assert lmap.n == 8 and lmap.embeddings.table.shape[0] == len(objects)
    assert lmap.source["background_objects"] == 0 and lmap.source["background_left_out"] == 2
    said = " ".join(r.getMessage() for r in caplog.records)
    assert "2 background objects" in said and "background=false" in said
    # per call, over the constructor's option
    assert adapter.read(path, background=True).n == 19


def test_a_map_saved_without_background_classes(tmp_path):
    """``bg_objects`` is None when ConceptGraphs maps without background classes."""
    rng = np.random.default_rng(1)
    objects = [_object(rng, 4, 6, (0.5, 0.5, 0.5))]
    path = save_conceptgraphs(tmp_path / "cg.pkl.gz", objects, None)
    lmap = read_map(path, allow_pickle=True)
    assert lmap.n == 4 and lmap.source["background_objects"] == 0


def test_a_malformed_background_object_names_its_field(tmp_path):
    rng = np.random.default_rng(2)
    bad = _object(rng, 3, 6, (0, 0, 0))
    del bad["pcd_np"]
    path = save_conceptgraphs(tmp_path / "cg.pkl.gz", [_object(rng, 4, 6, (0, 0, 0))], [bad])
    with pytest.raises(MapFormatError, match=r"bg_objects\[0\] has no field 'pcd_np'"):
        read_map(path, allow_pickle=True)
    assert read_map(path, allow_pickle=True, background=False).n == 4
    with pytest.raises(MapFormatError, match="option 'background' must be true or false"):
        read_map(path, allow_pickle=True, background="yes")
