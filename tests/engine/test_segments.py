"""engine/segments.py: a component is cut where its items' features change, only there."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import LatentMap
from quash_plugins.engine.segments import split_components
from quash_plugins.engine.topology import MapTopology


def _slab(nx=12, ny=8):
    cells = np.array([(x, y, 0) for x in range(nx) for y in range(ny)])
    return cells, MapTopology(LatentMap(np.ones((len(cells), 2), np.float32), grid_index=cells))


@pytest.mark.parametrize("seed", range(5))
def test_two_objects_are_cut_apart_and_one_object_is_not(seed):
    cells, topo = _slab()
    rng = np.random.default_rng(seed)
    left = cells[:, 0] < 4  # a 4x8 object beside an 8x8 one
    feats = 0.1 * rng.standard_normal((len(cells), 16))
    feats[left] += 1.0
    members = np.arange(len(cells))
    pieces, of = split_components([members], topo, lambda m: feats[m], 2.5, min_size=4)
    assert sorted(map(len, pieces)) == [32, 64] and of == [0, 0]
    assert {tuple(p) for p in pieces} == {
        tuple(np.flatnonzero(left)),
        tuple(np.flatnonzero(~left)),
    }
    same = 0.1 * rng.standard_normal((len(cells), 16))
    assert split_components([members], topo, lambda m: same[m], 2.5, min_size=4) == ([], [])


def test_sizes_bound_what_is_split_and_what_is_kept():
    cells, topo = _slab()
    rng = np.random.default_rng(0)
    feats = 0.1 * rng.standard_normal((len(cells), 16))
    feats[cells[:, 0] < 1] += 1.0  # an 8-item strip
    members = np.arange(len(cells))
    pieces, _ = split_components([members], topo, lambda m: feats[m], 2.5, min_size=4)
    assert sorted(map(len, pieces)) == [8, 88]
    # a strip under min_size is dropped; a component over max_size, or under twice
    # min_size, is not split at all
    assert [len(p) for p in split_components([members], topo, lambda m: feats[m], 2.5, 9)[0]] == [
        88
    ]
    assert split_components([members], topo, lambda m: feats[m], 2.5, 4, max_size=95) == ([], [])
    assert split_components([members], topo, lambda m: feats[m], 2.5, min_size=49) == ([], [])
