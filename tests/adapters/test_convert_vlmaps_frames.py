"""``quash convert --format vlmaps`` keeps positions where they are, whatever way the
source grid's cells are counted.

VLMaps' mobile-base cells (``row = gs/2 - x/cs``, ``col = gs/2 - y/cs``) and its 2023
top-down cells count rows and columns against the metric axes, so a writer that takes
cells from ``grid_index`` as they are turns the map 180 degrees about the vertical.
These maps are built from metric points with re-implementations of VLMaps' own forward
functions (``tests/_vlmaps_writers.py``); the expected positions and instance
centroids are computed from those points and from VLMaps' inverse functions, not from
the adapters.
"""

from __future__ import annotations

import numpy as np
import pytest
from _vlmaps_writers import (
    build_camera_map,
    build_lseg_grid,
    build_mobile_map,
    save_3d_map,
    save_3d_map_cam,
    save_lseg_folder,
    sha256,
    upstream_grid_id2base_pos_3d,
    upstream_grid_id2pos,
)

from quash_plugins.adapters import read_map, write_npz_map
from quash_plugins.cli.main import main
from quash_plugins.core.errors import UsageError
from quash_plugins.core.types import LatentMap
from quash_plugins.engine.instances import find_instances

pytest.importorskip("h5py")

D = 8
CS = 0.1
GS = 200


def _z_up(points):
    """Camera-base y-up positions, ``(x, z, -y)`` of a z-up map, turned back to z-up."""
    x, y, z = np.asarray(points, dtype=np.float64).T
    return np.column_stack([x, -z, y])


def _room(seed=0):
    """Points on both sides of the origin: a "sofa" box at x < 0, y > 0 (about
    (-4.4, 0.7), as in the report) and a "table" box at x > 0, y < 0, on a floor."""
    rng = np.random.default_rng(seed)
    floor = rng.uniform([-5.0, -3.0, 0.0], [3.0, 2.0, 0.04], size=(900, 3))
    sofa = rng.uniform([-4.8, 0.3, 0.1], [-4.0, 1.1, 0.8], size=(500, 3))
    table = rng.uniform([1.2, -2.4, 0.2], [2.0, -1.6, 0.7], size=(400, 3))
    pts = np.concatenate([floor, sofa, table])
    kind = np.repeat([0, 1, 2], [len(floor), len(sofa), len(table)])
    feats = rng.normal(size=(len(pts), D)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(len(pts), 3)).astype(np.uint8)
    return pts, kind, feats, rgb


def _convert(src, dst, *options):
    args = ["-q", "convert", str(src), str(dst), "--format", "vlmaps", "--force"]
    for opt in options:
        args += ["-o", opt]
    return main(args)


def _centroids(lmap, rows_of_objects):
    """Instance centroids (z-up for a y-up map) of each object's rows, largest first."""
    out = []
    for rows in rows_of_objects:
        mask = np.zeros(lmap.n, dtype=bool)
        mask[rows] = True
        inst = find_instances(lmap, mask, mask.astype(np.float32), min_size=1)
        centroid = np.asarray(inst[0].centroid, dtype=np.float64)
        out.append(_z_up(centroid[None])[0] if lmap.source.get("up") == "+y" else centroid)
    return np.array(out)


def test_mobile_base_map_keeps_positions_and_instance_centroids(tmp_path):
    pts, kind, feats, rgb = _room()
    arrays, row_of = build_mobile_map(pts, feats, rgb, gs=GS, cs=CS)
    path = save_3d_map(tmp_path / "scene" / "vlmap" / "vlmaps.h5df", **arrays)
    before = sha256(path)
    vl = tmp_path / "vl"
    assert _convert(path, vl, f"cs={CS}", "positions=upstream") == 0
    back = read_map(vl)
    assert back.source["up"] == "+y" and back.n == len(arrays["grid_pos"])
    # VLMaps' own grid_id2base_pos_3d of every cell, in the file's row order
    expected = np.array([upstream_grid_id2base_pos_3d(*c, CS, GS) for c in arrays["grid_pos"]])
    np.testing.assert_allclose(_z_up(back.positions), expected, atol=1e-5)
    # ... which is the face of each cell nearest the origin: less than a cell from
    # every true point in it (two cells wide at the origin index)
    kept = row_of >= 0
    gap = np.abs(_z_up(back.positions)[row_of[kept]] - pts[kept])
    assert (gap < 2 * CS + 1e-6).all() and (np.median(gap, axis=0) < CS).all()
    # rows keep their order: the same embeddings, and each object's cells
    np.testing.assert_array_equal(back.embeddings[()], arrays["grid_feat"])
    objects = [np.unique(row_of[(kind == k) & kept]) for k in (1, 2)]
    sofa, table = _centroids(back, objects)
    src = read_map(path, cs=CS, positions="upstream")
    np.testing.assert_allclose(_centroids(src, objects), [sofa, table], atol=1e-5)
    np.testing.assert_allclose(sofa, expected[objects[0]].mean(axis=0), atol=1e-5)
    np.testing.assert_allclose(table, expected[objects[1]].mean(axis=0), atol=1e-5)
    # the objects are where their points are (within a cell), not turned about z
    np.testing.assert_allclose(sofa[:2], pts[kind == 1, :2].mean(axis=0), atol=CS)
    np.testing.assert_allclose(table[:2], pts[kind == 2, :2].mean(axis=0), atol=CS)
    # and the camera-base grid is counted the way positions run
    for a in range(3):
        order = np.argsort(back.grid_index[:, a], kind="stable")
        assert (np.diff(np.asarray(back.positions, np.float64)[order, a]) >= -1e-6).all()
    assert sha256(path) == before


def test_mobile_base_cell_centres_on_one_side_convert_exactly(tmp_path):
    """Cell centres of a map off the origin cells are evenly spaced: written as they are."""
    pts, _, feats, rgb = _room(seed=1)
    pts = pts - pts.min(axis=0) + [0.35, 0.35, 0.35]  # every x, y, z > 0: k >= 3, h >= 3
    arrays, row_of = build_mobile_map(pts, feats, rgb, gs=GS, cs=CS)
    path = save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays)
    assert _convert(path, tmp_path / "vl", f"cs={CS}") == 0
    back, src = read_map(tmp_path / "vl"), read_map(path, cs=CS)
    np.testing.assert_allclose(_z_up(back.positions), src.positions, atol=1e-5)
    # the centre of each cell, independently: half a cell beyond the face at the origin side
    g = arrays["grid_pos"].astype(np.float64)
    centre = np.column_stack(
        [(GS // 2 - g[:, 0] + 0.5) * CS, (GS // 2 - g[:, 1] + 0.5) * CS, (g[:, 2] + 0.5) * CS]
    )
    np.testing.assert_allclose(_z_up(back.positions), centre, atol=1e-5)
    kept = row_of >= 0
    assert (np.abs(_z_up(back.positions)[row_of[kept]] - pts[kept]) <= CS / 2 + 1e-6).all()


def test_mobile_base_cell_centres_across_the_origin_are_refused(tmp_path, capsys):
    pts, _, feats, rgb = _room()
    arrays, _ = build_mobile_map(pts, feats, rgb, gs=GS, cs=CS)
    path = save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays)
    vl = tmp_path / "vl"
    assert _convert(path, vl, f"cs={CS}") == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "vlmaps.h5df" in err and "'positions'" in err and "positions=upstream" in err
    assert "--format npz" in err
    assert not (vl / "vlmap_cam" / "vlmaps_cam.h5df").exists()


def test_top_down_grid_keeps_positions_and_instance_centroids(tmp_path):
    rng = np.random.default_rng(3)
    # camera (x right, z forward): a "sofa" at x in (-1.1, -0.3), z in (-4.8, -4.0)
    floor = rng.uniform([-3.0, -5.0], [2.0, 3.0], size=(2500, 2))
    sofa = rng.uniform([-1.1, -4.8], [-0.3, -4.0], size=(300, 2))
    pts_xz = np.concatenate([floor, sofa])
    feats = rng.normal(size=(len(pts_xz), D)).astype(np.float32)
    grid, weight, cells = build_lseg_grid(pts_xz, feats, gs=GS, cs=CS)
    folder = save_lseg_folder(tmp_path / "scene", grid, weight)
    before = sha256(folder / "grid_lseg_1.npy")
    vl = tmp_path / "tdvl"
    assert _convert(tmp_path / "scene", vl, f"cs={CS}") == 2  # cell centres: refused
    assert _convert(tmp_path / "scene", vl, f"cs={CS}", "positions=upstream") == 0
    back = read_map(vl)
    src = read_map(tmp_path / "scene", cs=CS, positions="upstream")
    assert back.n == src.n
    # VLMaps' grid_id2pos of each observed cell, in the base frame (x = z_cam, y = -x_cam)
    rows, cols = np.nonzero(np.abs(grid).sum(axis=2) > 0)  # row-major, as the adapter
    cam = np.array([upstream_grid_id2pos(GS, CS, c, r) for r, c in zip(rows, cols)])
    expected = np.column_stack([cam[:, 1], -cam[:, 0], np.zeros(len(cam))])
    np.testing.assert_allclose(_z_up(back.positions), expected, atol=1e-5)
    # the sofa's cells, found from its points, are where the points are
    key = {(int(r), int(c)): i for i, (r, c) in enumerate(zip(rows, cols))}
    sofa_rows = np.unique([key[tuple(rc)] for rc in cells[len(floor) :]])
    centroid = _centroids(back, [sofa_rows])[0]
    np.testing.assert_allclose(centroid, _centroids(src, [sofa_rows])[0], atol=1e-5)
    np.testing.assert_allclose(centroid, expected[sofa_rows].mean(axis=0), atol=1e-5)
    true_xy = np.column_stack([sofa[:, 1], -sofa[:, 0]]).mean(axis=0)
    np.testing.assert_allclose(centroid[:2], true_xy, atol=CS)
    assert sha256(folder / "grid_lseg_1.npy") == before


def test_camera_base_map_is_written_as_it_is(tmp_path):
    pts, _, feats, rgb = _room(seed=2)
    arrays, row_of = build_camera_map(pts[:, [0, 2, 1]] * [1, 1, -1], feats, rgb, cs=CS)
    path = save_3d_map_cam(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays)
    assert _convert(path, tmp_path / "vl") == 0
    back, src = read_map(tmp_path / "vl"), read_map(path)
    np.testing.assert_allclose(back.positions, src.positions, atol=1e-5)
    expected = arrays["pcd_min"] + arrays["grid_pos"] * CS
    np.testing.assert_allclose(back.positions, expected, atol=1e-5)


def _npz_grid(path, positions, cells):
    emb = np.random.default_rng(0).normal(size=(len(cells), 4)).astype(np.float32)
    lmap = LatentMap(emb, kind="voxels", positions=positions, grid_index=cells, voxel_size=CS)
    return write_npz_map(lmap, path)


def test_a_grid_counted_against_its_positions_is_turned_back(tmp_path):
    """Any axis whose index runs against its positions, not only VLMaps'."""
    rng = np.random.default_rng(4)
    cells = np.stack(np.unravel_index(rng.choice(400, 40, replace=False), (8, 10, 5)), 1)
    pos = np.array([1.0, -2.0, 0.3]) + cells * [-CS, CS, -CS]
    src = _npz_grid(tmp_path / "g.npz", pos.astype(np.float32), cells)
    assert _convert(src, tmp_path / "vl") == 0
    np.testing.assert_allclose(_z_up(read_map(tmp_path / "vl").positions), pos, atol=1e-5)


def test_positions_off_their_cells_are_refused_or_rounded(tmp_path, capsys):
    from quash_plugins.adapters._vlmaps_write import write_vlmaps_map

    rng = np.random.default_rng(5)
    cells = np.stack(np.unravel_index(rng.choice(400, 40, replace=False), (8, 10, 5)), 1)
    pos = cells * CS + rng.uniform(-0.3, 0.3, size=cells.shape) * CS  # inside each cell
    src = _npz_grid(tmp_path / "g.npz", pos.astype(np.float32), cells)
    assert main(["convert", str(src), str(tmp_path / "vl"), "--format", "vlmaps"]) == 0
    assert "inside their cells" in " ".join(capsys.readouterr().err.split())
    back = _z_up(read_map(tmp_path / "vl").positions)
    assert (np.abs(back - pos) < CS / 2).all()
    # positions that are not their cells' (here: shuffled) are refused, naming both
    shuffled = _npz_grid(tmp_path / "s.npz", pos[rng.permutation(len(pos))], cells)
    with pytest.raises(UsageError, match=r"s\.npz.*'positions' and 'grid_index'.*--format npz"):
        write_vlmaps_map(read_map(shuffled), tmp_path / "vl2")
    assert not (tmp_path / "vl2").exists()
