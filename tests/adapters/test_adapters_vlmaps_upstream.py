"""VLMaps maps written the way VLMaps' own builders write them, read exactly.

The fixtures bin metric points with independent re-implementations of VLMaps' forward
functions (``base_pos2grid_id_3d``, the camera builder's rounding, the 2023
``pos2grid_id``; see ``tests/_vlmaps_writers.py``), so every cell comes with the true
points inside it. Positions are checked against those points (the reported centre
lies in the middle of the cell that holds them) and against re-implementations of
VLMaps' inverse functions (``grid_id2base_pos_3d``, ``grid_id2pos``).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import yaml
from _vlmaps_writers import (
    build_camera_map,
    build_lseg_grid,
    build_mobile_map,
    save_3d_map,
    save_3d_map_cam,
    save_lseg_folder,
    sha256,
    upstream_base_pos2grid_id_3d,
    upstream_grid_id2base_pos_3d,
    upstream_grid_id2pos,
)

from quash_plugins import Quash
from quash_plugins.adapters import read_map
from quash_plugins.core import registry
from quash_plugins.core.errors import EmptyMapWarning, MapFormatError

D = 8


def scene_points(n=400, seed=0, lo=(-2.0, -2.0, 0.0), hi=(2.0, 2.0, 1.4)):
    """Points on both sides of the origin, plus points near it (the 2-cell-wide cells)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(lo, hi, size=(n, 3))
    pts[:20, :2] = rng.uniform(-0.049, 0.049, size=(20, 2))
    pts[20:30, 2] = rng.uniform(0.0, 0.049, size=10)
    feats = rng.normal(size=(n, D)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(n, 3)).astype(np.float32)
    return pts, feats, rgb


def within_cell(points, centres, cs, origin_index_axes):
    """Each point lies in the cell centred at ``centres``: half a cell each way, a whole
    cell for the two-cell-wide origin cells (``origin_index_axes`` marks them)."""
    half = np.where(origin_index_axes, cs, cs / 2)
    return np.all(np.abs(points - centres) <= half + 1e-6, axis=1)


# ------------------------------------------------------------------------ mobile base
@pytest.mark.parametrize("gs", [400, 401])
def test_mobile_base_non_default_gs_read_from_file(tmp_path, gs):
    cs = 0.05
    pts, feats, rgb = scene_points()
    arrays, row_of = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=gs, cs=cs)
    path = save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays)
    before = sha256(path)
    lmap = read_map(tmp_path)  # no options: gs comes from occupied_ids
    assert lmap.source["gs"] == gs and lmap.source["gs_from"] == "occupied_ids"
    assert lmap.n == len(arrays["grid_feat"]) and lmap.source["positions"] == "centre"
    assert lmap.source["up"] == "+z"  # [row, col, height] in the base frame
    kept = row_of >= 0
    assert kept.sum() > 300
    cells = arrays["grid_pos"][row_of[kept]]
    centres = lmap.positions[row_of[kept]].astype(np.float64)
    origin = np.column_stack([cells[:, 0] == gs // 2, cells[:, 1] == gs // 2, cells[:, 2] == 0])
    assert origin[:, 0].any() and origin[:, 2].any()  # the special cells are exercised
    assert within_cell(pts[kept], centres, cs, origin).all()
    # every reported centre bins back into its own cell with VLMaps' forward function
    for (x, y, z), cell in zip(lmap.positions.astype(np.float64), arrays["grid_pos"]):
        assert upstream_base_pos2grid_id_3d(gs, cs, x, y, z) == tuple(int(v) for v in cell)
    # positions="upstream" is VLMaps' own inverse, exactly
    up = read_map(path, positions="upstream")
    expected = np.array([upstream_grid_id2base_pos_3d(*c, cs, gs) for c in arrays["grid_pos"]])
    np.testing.assert_allclose(up.positions, expected, atol=1e-6)
    # the face nearest the origin: half a cell inward of the centre off the origin cells
    gap = np.abs(lmap.positions.astype(np.float64)) - np.abs(up.positions.astype(np.float64))
    if gs % 2 == 0:
        assert np.all(np.isclose(gap, 0.0, atol=1e-6) | np.isclose(gap, cs / 2, atol=1e-6))
    assert sha256(path) == before


def test_mobile_base_configured_gs_must_agree(tmp_path):
    pts, feats, rgb = scene_points(n=60)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=400, cs=0.05)
    path = save_3d_map(tmp_path / "m.h5df", **arrays)
    with pytest.raises(MapFormatError) as err:
        read_map(path, gs=1000)
    msg = str(err.value)
    assert "m.h5df" in msg and "gs=1000" in msg and "400" in msg and "occupied_ids" in msg
    assert read_map(path, gs=400).source["gs"] == 400  # an agreeing value is fine
    # the 15 m that a silent default would have cost: (1000 - 400) / 2 * 0.05
    up = read_map(path, positions="upstream").positions
    row = arrays["grid_pos"][:, 0].astype(np.float64)
    np.testing.assert_allclose((500 - row) * 0.05 - up[:, 0], 15.0, atol=1e-5)


def test_mobile_base_without_occupied_ids_uses_option(tmp_path, caplog):
    pts, feats, rgb = scene_points(n=60)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=400, cs=0.05)
    path = tmp_path / "fork.h5df"
    import h5py

    with h5py.File(path, "w") as f:  # a fork that keeps only the per-row arrays
        for key in ("grid_feat", "grid_pos", "grid_rgb"):
            f.create_dataset(key, data=arrays[key])
    assert read_map(path, gs=400).source["gs_from"] == "option"
    with caplog.at_level("WARNING"):
        lmap = read_map(path)
    assert lmap.source["gs"] == 1000 and "assuming VLMaps' default gs" in caplog.text


def test_mobile_base_grid_out_of_range_is_an_error(tmp_path):
    pts, feats, rgb = scene_points(n=60)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=400, cs=0.05)
    arrays["grid_pos"] = arrays["grid_pos"].copy()
    arrays["grid_pos"][3, 0] = 400
    path = save_3d_map(tmp_path / "bad.h5df", **arrays)
    with pytest.raises(MapFormatError, match=r"bad\.h5df.*grid_pos.*outside \[0, 400\)"):
        read_map(path)


def test_empty_mobile_map_reads_and_queries_empty(tmp_path, capsys):
    from quash_plugins.cli.main import main

    pts = np.array([[100.0, 0.0, 0.5], [0.0, 0.0, -1.0]])  # out of range, below the floor
    arrays, row_of = build_mobile_map(
        pts, np.ones((2, D), np.float32), np.zeros((2, 3), np.uint8), gs=200, cs=0.05
    )
    assert (row_of == -1).all() and arrays["grid_feat"].shape == (0, D)
    path = save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays)
    lmap = read_map(path)
    assert (lmap.n, lmap.dim) == (0, D) and lmap.positions.shape == (0, 3)
    assert lmap.source["frames_fused"] == 5
    table = {w: np.eye(D)[i].tolist() for i, w in enumerate(["chair", "other", "background"])}
    table["nothing"] = np.eye(D)[3].tolist()
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(table))
    cfg = tmp_path / "q.yaml"
    cfg.write_text("encoder: {name: table, file: t.yaml}\nclassifier: contrast\ncache: false\n")
    with pytest.warns(EmptyMapWarning):
        res = Quash.from_config(cfg).query(path, "chair")
    assert res.mask.shape == (0,) and res.instances == []
    out = tmp_path / "r.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EmptyMapWarning)
        assert main(["query", str(path), "chair", "-c", str(cfg), "--out", str(out)]) == 0
        assert main(["convert", str(path), str(tmp_path / "e.npz")]) == 0
    with np.load(out) as z:
        assert z["masks"].shape == (1, 0)
    assert read_map(tmp_path / "e.npz").n == 0


def test_float16_features(tmp_path):
    pts, feats, rgb = scene_points(n=80)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=300, cs=0.1)
    arrays["grid_feat"] = arrays["grid_feat"].astype(np.float16)
    path = save_3d_map(tmp_path / "m.h5df", **arrays)
    lmap = read_map(path, cs=0.1)
    assert lmap.dtype == np.float16
    got = np.concatenate([b for _, _, b in lmap.iter_chunks(16)])
    ref = arrays["grid_feat"].astype(np.float32)
    ref /= np.linalg.norm(ref, axis=1, keepdims=True)
    np.testing.assert_allclose(got, ref, atol=1e-6)


# ------------------------------------------------------------------------ camera base
def test_camera_base_as_the_camera_builder_writes_it(tmp_path):
    cs = 0.04
    pts, feats, rgb = scene_points(n=300, lo=(-1.5, -0.3, 0.5), hi=(2.0, 1.2, 3.0), seed=4)
    arrays, row_of = build_camera_map(pts, feats, rgb, cs=cs)
    assert arrays["weight"].dtype == np.float64 and arrays["grid_rgb"].dtype == np.float32
    path = save_3d_map_cam(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays)
    lmap = read_map(tmp_path)
    assert lmap.source["pose_type"] == "camera_base" and lmap.voxel_size == pytest.approx(cs)
    assert lmap.source["grid_shape"] == list(arrays["occupied_ids"].shape)
    expected = arrays["pcd_min"] + arrays["grid_pos"].astype(np.float64) * cs
    np.testing.assert_allclose(lmap.positions, expected, atol=1e-5)
    # rounding bins each point into the cell centred on its grid point
    centres = lmap.positions[row_of].astype(np.float64)
    assert np.all(np.abs(pts - centres) <= cs / 2 + 1e-5)
    np.testing.assert_array_equal(lmap.colors, np.clip(np.rint(arrays["grid_rgb"]), 0, 255))
    # cells are [row, height, col]: the builder's top-down image keeps, per (row, col),
    # the point of largest height, so the map is y-up, which the viewer is told
    assert lmap.source["up"] == "+y"
    # "upstream" changes nothing: pcd_min + grid_pos * cs is exact for camera maps
    np.testing.assert_array_equal(read_map(path, positions="upstream").positions, lmap.positions)
    with pytest.raises(MapFormatError) as err:
        read_map(path, cs=0.05)
    assert "cs=0.05" in str(err.value) and "0.04" in str(err.value) and "'cs'" in str(err.value)
    assert read_map(path, cs=0.04).n == lmap.n


# ------------------------------------------------------------------------ live object
def test_live_object_gs_from_occupied_ids(tmp_path, caplog):
    from types import SimpleNamespace

    pts, feats, rgb = scene_points(n=100)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=400, cs=0.05)
    path = save_3d_map(tmp_path / "m.h5df", **arrays)
    from_file = read_map(path).positions
    live = SimpleNamespace(**arrays, gs=400, cs=0.05)
    np.testing.assert_array_equal(read_map(live).positions, from_file)
    live.gs = 1000  # the VLMaps config disagrees with the loaded arrays
    with caplog.at_level("WARNING"):
        np.testing.assert_array_equal(read_map(live).positions, from_file)
    assert "disagrees with occupied_ids" in caplog.text
    with pytest.raises(MapFormatError, match=r"gs=1000.*400"):
        read_map(live, gs=1000)
    empty = SimpleNamespace(
        grid_feat=np.zeros((0, D), np.float32), grid_pos=np.zeros((0, 3), np.int32)
    )
    assert read_map(empty, "vlmaps-live", gs=1000).n == 0


# ------------------------------------------------------------------------ adapter options
def test_adapter_auto_applies_the_configs_adapter_options(tmp_path, capsys):
    """`--adapter auto` keeps the options the config gives for the adapter it picks."""
    from quash_plugins.cli.main import main

    pts, feats, rgb = scene_points(n=80)
    arrays, _ = build_mobile_map(pts, feats, rgb.astype(np.uint8), gs=300, cs=0.1)
    path = save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays)
    table = {w: np.eye(D)[i].tolist() for i, w in enumerate(["chair", "other", "background"])}
    table["nothing"] = np.eye(D)[3].tolist()
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(table))
    for adapter in ("vlmaps", "auto"):
        cfg = tmp_path / f"{adapter}.yaml"
        cfg.write_text(
            "encoder: {name: table, file: t.yaml}\nclassifier: contrast\ncache: false\n"
            f"adapter: {{name: {adapter}, cs: 0.1, positions: upstream}}\n"
        )
        q = Quash.from_config(cfg)
        for name in (None, "auto"):
            lmap = q.read_map(path, adapter=name)
            assert lmap.source["cs"] == 0.1 and lmap.source["positions"] == "upstream"
        rc = main(["query", str(path), "chair", "-c", str(cfg), "--adapter", "auto", "--json"])
        assert rc == 0
        report = json.loads(capsys.readouterr().out)
        assert report["map"]["cs"] == 0.1 and report["map"]["positions"] == "upstream"
    # another adapter named on the command line does not receive the config's options
    q = Quash.from_config(tmp_path / "vlmaps.yaml")
    assert q.read_map(path, adapter="vlmaps", cs=0.2).source["cs"] == 0.2


# ------------------------------------------------------------------------ 2023 grids
@pytest.mark.parametrize("gs", [40, 41])
def test_2023_grid_positions_both_signs(tmp_path, gs):
    cs = 0.1
    rng = np.random.default_rng(2)
    xz = rng.uniform(-1.9, 1.9, size=(500, 2))
    xz[:15] = rng.uniform(-0.099, 0.099, size=(15, 2))  # the two-cell-wide origin cells
    feats = rng.normal(size=(500, D)).astype(np.float32)
    grid, weight, cells = build_lseg_grid(xz, feats, gs=gs, cs=cs)
    assert weight.dtype == np.float64
    folder = save_lseg_folder(tmp_path / "scene", grid, weight)
    a2d = registry.create("adapters", "vlmaps-2d", cs=cs)
    lmap = a2d.read(folder)
    flat = lmap.grid_index[:, 0] * gs + lmap.grid_index[:, 1]
    item_of = {int(c): i for i, c in enumerate(flat)}
    kept = cells[:, 0] >= 0
    idx = np.array([item_of[int(r * gs + c)] for r, c in cells[kept]])
    # our frame: x forward = camera z, y left = -camera x
    truth = np.column_stack([xz[kept, 1], -xz[kept, 0]])
    origin = np.column_stack([cells[kept, 0] == gs // 2, cells[kept, 1] == gs // 2])
    assert origin.any(axis=0).all()
    assert within_cell(truth, lmap.positions[idx, :2].astype(np.float64), cs, origin).all()
    assert (lmap.positions[:, 2] == 0).all()
    assert lmap.source["up"] == "+z"  # the mobile-base frame, one flat layer
    up = a2d.read(folder, positions="upstream")
    for (row, col, _), (x, y, _) in zip(up.grid_index, up.positions.astype(np.float64)):
        xx, zz = upstream_grid_id2pos(gs, cs, col, row)
        assert x == pytest.approx(zz, abs=1e-6) and y == pytest.approx(-xx, abs=1e-6)


def test_2023_grid_half_cell_sign(tmp_path):
    """The issue's worked example: gs = 1000, cs = 0.05, points on both sides."""
    xz = np.array([[-0.07, 0.12], [0.07, -0.12], [0.03, -0.03]])
    grid, weight, cells = build_lseg_grid(xz, np.eye(3, D, dtype=np.float32), gs=1000, cs=0.05)
    assert cells.tolist() == [[498, 499], [502, 501], [500, 500]]
    lmap = registry.create("adapters", "vlmaps-2d").read(save_lseg_folder(tmp_path, grid, weight))
    by_cell = {tuple(g[:2]): p for g, p in zip(lmap.grid_index.tolist(), lmap.positions)}
    # centres in camera (x, z): (-0.075, 0.125), (0.075, -0.125), (0, 0)
    np.testing.assert_allclose(by_cell[(498, 499)][:2], [0.125, 0.075], atol=1e-6)
    np.testing.assert_allclose(by_cell[(502, 501)][:2], [-0.125, -0.075], atol=1e-6)
    np.testing.assert_allclose(by_cell[(500, 500)][:2], [0.0, 0.0], atol=1e-6)
