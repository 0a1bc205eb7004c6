"""Float32 maps handed out as views (a file's read-only memory map, a caller's own array
such as a live VLMap's ``grid_feat``): queries on maps that ask for normalisation read
them and never write into them (tests/adapters/test_read_only_maps.py checks every
adapter's files)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from _cf_writers import save_openlex3d
from _vlmaps_writers import write_vlmaps_2d

from quash_plugins import Quash, registry
from quash_plugins.encoders import TableEncoder

TABLE = {"chair": [1, 0, 0, 0], "other": [0, 1, 0, 0], "background": [0, 0, 1, 0],
         "nothing": [0, 0, 0, 1]}  # fmt: skip


def quash():
    return Quash(TableEncoder(table=TABLE), classifier=registry.create("classifiers", "contrast"))


def rows(n, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.normal(size=(n, 4)) * rng.uniform(0.5, 5, (n, 1))).astype(np.float32)


def expected_mask(feat):
    u = feat / np.linalg.norm(feat, axis=1, keepdims=True)
    return u[:, 0] > u[:, 1:].max(axis=1)


def test_live_vlmap_array_is_never_changed():
    feat = rows(30)
    before = feat.copy()
    live = SimpleNamespace(grid_feat=feat, grid_pos=np.full((30, 3), 5), gs=10)
    res = quash().query(live, "chair")
    np.testing.assert_array_equal(feat, before)
    np.testing.assert_array_equal(res.mask, expected_mask(before))


def test_float32_frames_dense_openlex3d_and_full_2d_grids(tmp_path):
    pytest.importorskip("open3d")
    feat = rows(24, seed=1)
    np.save(tmp_path / "frame1.npy", feat.reshape(4, 6, 4))
    res = quash().query(tmp_path, "chair", adapter="image-features")
    np.testing.assert_array_equal(res.mask, expected_mask(feat))
    save_openlex3d(tmp_path / "ol", np.zeros((24, 3)), None, feat, np.arange(24))
    res = quash().query(tmp_path / "ol", "chair")
    np.testing.assert_array_equal(res.mask, expected_mask(feat))
    folder, ref = write_vlmaps_2d(tmp_path / "scene", gs=6, d=4, observed=1.0)
    res = quash().query(folder, "chair", adapter="vlmaps-2d", keep_empty=True)
    np.testing.assert_array_equal(res.mask, expected_mask(ref["grid"].reshape(36, 4)))
    np.testing.assert_array_equal(np.load(folder / "grid_lseg_1.npy"), ref["grid"])
