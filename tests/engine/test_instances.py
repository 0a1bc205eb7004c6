"""Instance grouping: voxel connectivity, point radius/DBSCAN grouping, per-frame pixels."""

from __future__ import annotations

import time

import numpy as np
import pytest

from quash_plugins import Quash
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError
from quash_plugins.core.types import FrameInfo, LatentMap
from quash_plugins.engine.instances import find_instances


def voxel_map(cells, cs=0.1):
    cells = np.asarray(cells, dtype=np.int64)
    return LatentMap(
        np.ones((len(cells), 2), np.float32),
        kind="voxels",
        grid_index=cells,
        voxel_size=cs,
        positions=(cells * cs).astype(np.float32),
    )


def blob(origin, shape):
    o = np.asarray(origin)
    return np.array(
        [o + (i, j, k) for i in range(shape[0]) for j in range(shape[1]) for k in range(shape[2])]
    )


def test_voxel_groups_stats_and_order():
    a = blob((0, 0, 0), (2, 2, 2))  # 8 cells
    b = blob((10, 10, 10), (1, 1, 4))  # 4 cells
    c = blob((20, 0, 0), (1, 1, 2))  # 2 cells, below min_size
    cells = np.concatenate([b, a, c])
    m = voxel_map(cells)
    scores = np.linspace(0, 1, len(cells)).astype(np.float32)
    inst = find_instances(m, np.ones(len(cells), bool), scores)
    assert [i.size for i in inst] == [8, 4]
    assert [i.id for i in inst] == [0, 1]
    a_idx = np.arange(4, 12)
    np.testing.assert_array_equal(inst[0].indices, a_idx)
    np.testing.assert_allclose(inst[0].centroid, (a * 0.1).mean(axis=0), atol=1e-6)
    np.testing.assert_allclose(inst[0].bbox_min, [0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(inst[0].bbox_max, [0.1, 0.1, 0.1], atol=1e-6)
    assert inst[0].mean_score == pytest.approx(scores[a_idx].mean(), rel=1e-5)
    assert inst[1].frame_id is None
    assert len(find_instances(m, np.ones(len(cells), bool), scores, min_size=1)) == 3
    assert len(find_instances(m, np.ones(len(cells), bool), scores, max_instances=1)) == 1


def test_voxel_connectivity_26_vs_6_and_mask():
    diag = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]])
    m = voxel_map(diag)
    s = np.ones(4, np.float32)
    assert [i.size for i in find_instances(m, np.ones(4, bool), s, min_size=1)] == [4]
    assert len(find_instances(m, np.ones(4, bool), s, min_size=1, connectivity=6)) == 4
    edge = voxel_map([[0, 0, 0], [1, 1, 0]])
    assert len(find_instances(edge, np.ones(2, bool), s[:2], min_size=1, connectivity=18)) == 1
    assert len(find_instances(edge, np.ones(2, bool), s[:2], min_size=1, connectivity=6)) == 2
    # unmatched items split groups
    line = voxel_map([[i, 0, 0] for i in range(7)])
    mask = np.array([1, 1, 1, 0, 1, 1, 1], bool)
    assert [i.size for i in find_instances(line, mask, np.ones(7, np.float32))] == [3, 3]


def test_voxels_without_grid_index_use_voxel_size():
    cells = np.concatenate([blob((0, 0, 0), (3, 1, 1)), blob((5, 5, 5), (3, 1, 1))])
    m = LatentMap(
        np.ones((6, 2), np.float32),
        kind="voxels",
        voxel_size=0.05,
        positions=(cells * 0.05).astype(np.float32),
    )
    assert [i.size for i in find_instances(m, np.ones(6, bool), np.ones(6))] == [3, 3]


def test_point_radius_grouping_and_dbscan():
    rng = np.random.default_rng(0)
    a = rng.normal([0, 0, 0], 0.05, (40, 3))
    b = rng.normal([3, 0, 0], 0.05, (25, 3))
    noise = np.array([[10.0, 10, 10]])
    pts = np.concatenate([a, b, noise]).astype(np.float32)
    m = LatentMap(np.ones((len(pts), 2), np.float32), kind="points", positions=pts)
    s = np.ones(len(pts), np.float32)
    mask = np.ones(len(pts), bool)
    for kw in ({"radius": 0.5}, {"radius": 0.5, "chunk": 7}, {}):
        inst = find_instances(m, mask, s, **kw)
        assert [i.size for i in inst] == [40, 25], kw
        np.testing.assert_allclose(inst[1].centroid, b.mean(axis=0), atol=1e-5)
        np.testing.assert_allclose(inst[1].bbox_max, b.max(axis=0), atol=1e-5)
    inst = find_instances(m, mask, s, method="dbscan", radius=0.5, min_samples=3, min_size=1)
    assert [i.size for i in inst] == [40, 25]  # the lone point is DBSCAN noise


def test_pixel_groups_per_frame():
    frames = [FrameInfo("f0", 6, 8, 0), FrameInfo("f1", 5, 5, 48)]
    n = 48 + 25
    mask = np.zeros(n, bool)
    img0 = np.zeros((6, 8), bool)
    img0[1:3, 1:4] = True  # 6 pixels
    img0[4, 6] = img0[5, 7] = img0[3, 5] = True  # a diagonal chain of 3
    img1 = np.zeros((5, 5), bool)
    img1[0:2, 0:2] = True
    mask[:48] = img0.ravel()
    mask[48:] = img1.ravel()
    m = LatentMap(np.ones((n, 2), np.float32), kind="pixels", frames=frames)
    inst = find_instances(m, mask, np.ones(n, np.float32))
    assert [(i.size, i.frame_id) for i in inst] == [(6, "f0"), (4, "f1"), (3, "f0")]
    np.testing.assert_allclose(inst[0].centroid, [2.0, 1.5, 0.0])  # (x=col, y=row)
    np.testing.assert_allclose(inst[1].bbox_max, [1, 1, 0])
    assert set(inst[1].indices) == {48, 49, 53, 54}
    four = find_instances(m, mask, np.ones(n, np.float32), connectivity=4)
    assert [(i.size, i.frame_id) for i in four] == [(6, "f0"), (4, "f1")]


def test_options_are_checked():
    m = voxel_map([[0, 0, 0]])
    with pytest.raises(ConfigError, match="min_sz"):
        find_instances(m, np.ones(1, bool), np.ones(1), min_sz=1)
    with pytest.raises(ConfigError, match="connectivity"):
        find_instances(m, np.ones(1, bool), np.ones(1), min_size=1, connectivity=5)
    assert find_instances(m, np.ones(1, bool), np.ones(1), method="none") == []
    assert find_instances(m, np.zeros(1, bool), np.ones(1)) == []


def test_fast_on_a_million_items_with_sparse_mask():
    rng = np.random.default_rng(0)
    n = 1_000_000
    cells = rng.integers(0, 300, (n, 3))
    cells[:64] = blob((500, 500, 500), (4, 4, 4))  # one planted object outside the noise
    m = LatentMap(np.zeros((n, 1), np.float32), kind="voxels", grid_index=cells, voxel_size=0.05)
    mask = np.zeros(n, bool)
    mask[:64] = True
    mask[rng.choice(np.arange(64, n), 5000, replace=False)] = True
    find_instances(m, mask, np.ones(n, np.float32))  # warm imports
    t = time.perf_counter()
    inst = find_instances(m, mask, np.ones(n, np.float32))
    assert time.perf_counter() - t < 2.0
    assert inst[0].size == 64 and set(inst[0].indices) == set(range(64))
    pts = rng.uniform(0, 100, (n, 3)).astype(np.float32)
    mp = LatentMap(np.zeros((n, 1), np.float32), kind="points", positions=pts)
    t = time.perf_counter()
    find_instances(mp, mask, np.ones(n, np.float32), radius=0.5)
    assert time.perf_counter() - t < 2.0


def test_query_results_carry_instances():
    d = 4
    table = {
        w: np.eye(d)[i].tolist() for i, w in enumerate(["chair", "other", "background", "nothing"])
    }
    cells = np.concatenate(
        [blob((0, 0, 0), (2, 2, 1)), blob((9, 9, 0), (3, 1, 1)), blob((20, 0, 0), (2, 2, 2))]
    )
    emb = np.zeros((len(cells), d), np.float32)
    emb[:7, 0] = 1  # chair: two groups
    emb[7:, 1] = 1
    m = LatentMap(
        emb,
        kind="voxels",
        grid_index=cells,
        voxel_size=0.1,
        positions=(cells * 0.1).astype(np.float32),
    )
    enc = registry.create("encoders", "table", table=table)
    q = Quash(enc, classifier=registry.create("classifiers", "contrast"))
    res = q.query(m, "chair")
    assert [i.size for i in res.instances] == [4, 3]
    q2 = Quash(
        enc, classifier=registry.create("classifiers", "contrast"), instances={"min_size": 4}
    )
    assert [i.size for i in q2.query(m, "chair").instances] == [4]
