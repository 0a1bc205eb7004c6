"""Every map writer is public: imported from ``quash_plugins.adapters``, map first.

``write_npz_streaming`` (what ``quash convert`` uses for lazy maps) and
``write_vlmaps_map`` (``quash convert --format vlmaps``) sit beside ``write_npz_map``;
each writes a map that its own adapter reads back unchanged.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import quash_plugins.adapters as adapters
from quash_plugins.adapters import write_npz_streaming, write_vlmaps_map
from quash_plugins.adapters._npz import NpzAdapter
from quash_plugins.core.types import LatentMap


def _voxel_map() -> LatentMap:
    """A small z-up voxel map: 12 distinct cells of 0.25 m, float32 rows, labels, colours."""
    rng = np.random.default_rng(3)
    flat = rng.choice(4 * 5 * 6, size=12, replace=False)
    cells = np.stack(np.unravel_index(flat, (4, 5, 6)), axis=1).astype(np.int64)
    return LatentMap(
        rng.normal(size=(12, 5)).astype(np.float32),
        kind="voxels",
        positions=cells * 0.25 + np.array([1.0, -2.0, 0.5]),
        colors=rng.integers(0, 256, size=(12, 3), dtype=np.uint8),
        labels=rng.integers(0, 3, size=12),
        label_names=["floor", "chair", "table"],
        voxel_size=0.25,
        grid_index=cells,
    )


def test_the_writers_are_exported_beside_write_npz_map():
    for name in ("write_npz_map", "write_npz_streaming", "write_vlmaps_map"):
        assert name in adapters.__all__
        assert name in dir(adapters)
    assert adapters.write_npz_streaming.__module__ == "quash_plugins.adapters._convert"
    assert adapters.write_vlmaps_map.__module__ == "quash_plugins.adapters._vlmaps_write"


def test_write_npz_streaming_round_trips_through_the_npz_adapter(tmp_path):
    lmap = _voxel_map()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (lmap, path) is the order that does not warn
        out = write_npz_streaming(lmap, tmp_path / "m.npz", chunk_rows=5)
    assert out == tmp_path / "m.npz"
    back = NpzAdapter().read(out)
    np.testing.assert_array_equal(np.asarray(back.embeddings), np.asarray(lmap.embeddings))
    assert np.asarray(back.embeddings).dtype == np.float32
    for key in ("positions", "colors", "labels", "grid_index"):
        np.testing.assert_array_equal(getattr(back, key), getattr(lmap, key), err_msg=key)
    assert back.label_names == lmap.label_names
    assert back.voxel_size == pytest.approx(0.25)


def test_write_vlmaps_map_round_trips_through_the_vlmaps_adapter(tmp_path):
    pytest.importorskip("h5py")
    from quash_plugins.adapters._vlmaps import VLMapsAdapter

    lmap = _voxel_map()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = write_vlmaps_map(lmap, tmp_path / "scene", chunk_rows=5)
    assert out == tmp_path / "scene" / "vlmap_cam" / "vlmaps_cam.h5df"
    back = VLMapsAdapter().read(tmp_path / "scene")
    assert back.source["up"] == "+y"
    np.testing.assert_array_equal(np.asarray(back.embeddings[()]), np.asarray(lmap.embeddings))
    np.testing.assert_array_equal(back.colors, lmap.colors)
    np.testing.assert_array_equal(back.labels, lmap.labels)
    assert back.label_names == lmap.label_names
    assert back.voxel_size == pytest.approx(0.25)
    # a z-up map is turned to VLMaps' y-up frame: (x, y, z) -> (x, z, -y), rows in order
    x, y, z = np.asarray(lmap.positions).T
    np.testing.assert_allclose(back.positions, np.column_stack([x, z, -y]), atol=1e-6)
    i, j, k = np.asarray(lmap.grid_index).T
    turned = np.column_stack([i, k, -j])
    np.testing.assert_array_equal(back.grid_index, turned - turned.min(axis=0))
