"""``to_vlmaps_grid``: a vlmaps-2d query's rows back on VLMaps' (gs, gs) grid."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.adapters import read_map, to_vlmaps_grid
from quash_plugins.adapters._vlmaps2d import VLMaps2DAdapter
from quash_plugins.core.errors import QuashError


@pytest.fixture
def map2d(tmp_path):
    folder = VLMaps2DAdapter().write_example(tmp_path)
    return folder, read_map(folder, "vlmaps-2d")


def test_rows_land_on_their_cells(map2d):
    folder, lmap = map2d
    grid = np.load(folder / "grid_lseg_1.npy")
    observed = np.abs(grid).sum(axis=2) > 0
    assert (to_vlmaps_grid(np.ones(lmap.n, bool), lmap) == observed).all()
    # a score per row is found at its own cell, in grid_lseg_1.npy's [row, col] order
    scores = np.arange(lmap.n, dtype=np.float32)
    on_grid = to_vlmaps_grid(scores, lmap)
    assert on_grid.shape == observed.shape and np.isnan(on_grid[~observed]).all()
    rows, cols = np.nonzero(observed)
    for i in (0, lmap.n // 2, lmap.n - 1):
        r, c = int(lmap.grid_index[i, 0]), int(lmap.grid_index[i, 1])
        assert on_grid[r, c] == i
        np.testing.assert_array_equal(lmap.embeddings[i], grid[r, c])
    assert sorted(zip(rows.tolist(), cols.tolist())) == sorted(
        map(tuple, lmap.grid_index[:, :2].tolist())
    )


def test_stacked_queries_and_fill(map2d):
    _, lmap = map2d
    masks = np.zeros((2, lmap.n), bool)
    masks[1, 3] = True
    out = to_vlmaps_grid(masks, lmap)
    assert out.shape == (2, 24, 24) and out.dtype == bool
    assert out[1].sum() == 1 and out[1][tuple(lmap.grid_index[3, :2])]
    assert (to_vlmaps_grid(np.zeros(lmap.n), lmap, fill=-1.0) == -1).sum() == 24 * 24 - lmap.n


def test_refuses_other_maps_and_wrong_lengths(map2d, tmp_path):
    from quash_plugins.adapters._vlmaps import VLMapsAdapter

    _, lmap = map2d
    with pytest.raises(QuashError, match=r"\(N,\) or \(Q, N\) with N = "):
        to_vlmaps_grid(np.ones(lmap.n + 1), lmap)
    lmap3d = read_map(VLMapsAdapter().write_example(tmp_path / "3d"))
    with pytest.raises(QuashError, match=r"vlmaps-2d.*grid_pos\[mask\]"):
        to_vlmaps_grid(np.ones(lmap3d.n, bool), lmap3d)
