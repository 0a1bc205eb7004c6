"""Fixture writers that follow VLMaps' own on-disk formats (written for these tests).

3D (``vlmaps/utils/mapping_utils.py::save_3d_map`` and ``VLMapBuilderCam.save_3d_map``):
datasets ``mapped_iter_list`` int32, ``grid_feat`` (N, D) float32, ``grid_pos`` (N, 3)
int32, ``weight`` (N,) float32, ``occupied_ids`` (gs, gs, vh) int32 (-1 empty, else row),
``grid_rgb`` (N, 3) uint8; camera-base files add ``pcd_min``/``pcd_max`` (3,) float64 and a
scalar ``cs``. 2D (``create_lseg_map_batch``): ``map/grid_lseg_1.npy`` (gs, gs, D) float32,
``color_top_down_1.npy`` (gs, gs, 3) uint8, ``grid_1_gt.npy`` (gs, gs) int32,
``obstacles.npy`` (gs, gs) uint8, ``weight_lseg_1.npy`` (gs, gs) float64.

:func:`mobile_map` / :func:`write_vlmaps_h5df` write arrays of random cells. The builders
below (:func:`build_mobile_map`, :func:`build_camera_map`, :func:`build_lseg_grid`) bin
metric points the way VLMaps' own builders do, and :func:`save_3d_map`,
:func:`save_3d_map_cam` and :func:`save_lseg_folder` save them as its save functions do,
so tests know the true points behind every cell (both signs of the origin, any gs,
camera base, empty maps).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import h5py
import numpy as np

#: The datasets VLMaps' camera-base ``VLMapBuilderCam.save_3d_map`` writes, in its order
#: (what ``quash convert --format vlmaps`` writes and ``VLMap.load_map`` reads back).
CAMERA_FIELDS = (
    "mapped_iter_list",
    "grid_feat",
    "grid_pos",
    "weight",
    "occupied_ids",
    "grid_rgb",
    "pcd_min",
    "pcd_max",
    "cs",
)


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def mobile_map(n=50, d=8, gs=60, vh=12, seed=0, dtype=np.float32):
    """Arrays of a mobile-base map with distinct cells and arbitrary feature norms."""
    rng = np.random.default_rng(seed)
    cells = rng.choice(gs * gs * vh, size=n, replace=False)
    grid_pos = np.stack(np.unravel_index(cells, (gs, gs, vh)), axis=1).astype(np.int32)
    feat = rng.normal(size=(n, d)) * rng.uniform(0.2, 5.0, size=(n, 1))
    return {
        "grid_feat": feat.astype(dtype),
        "grid_pos": grid_pos,
        "weight": rng.uniform(0.1, 3.0, size=n).astype(np.float32),
        "grid_rgb": rng.integers(0, 256, size=(n, 3), dtype=np.uint8),
        "gs": gs,
        "vh": vh,
    }


def write_vlmaps_h5df(path, arrays, *, semantic=None, camera=None, drop=(), extra=None):
    """Write ``arrays`` (from :func:`mobile_map`) the way VLMaps' save_3d_map does."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    gs, vh = arrays["gs"], arrays["vh"]
    n = len(arrays["grid_pos"])
    occupied = -np.ones((gs, gs, vh), dtype=np.int32)
    gp = arrays["grid_pos"]
    if gp.ndim == 2 and gp.shape[1] == 3 and len(gp):
        ok = (gp >= 0).all(axis=1) & (gp < [gs, gs, vh]).all(axis=1)
        occupied[gp[ok, 0], gp[ok, 1], gp[ok, 2]] = np.arange(n, dtype=np.int32)[ok]
    data = {
        "mapped_iter_list": np.arange(7, dtype=np.int32),
        "grid_feat": arrays["grid_feat"],
        "grid_pos": arrays["grid_pos"],
        "weight": arrays["weight"],
        "occupied_ids": occupied,
        "grid_rgb": arrays["grid_rgb"],
    }
    if camera is not None:
        data["pcd_min"] = np.asarray(camera["pcd_min"], dtype=np.float64)
        data["pcd_max"] = np.asarray(camera["pcd_max"], dtype=np.float64)
        data["cs"] = np.float64(camera["cs"])
    if semantic is not None:
        data["grid_semantic"] = np.asarray(semantic)
    data.update(extra or {})
    with h5py.File(path, "w") as f:
        for key, value in data.items():
            if key not in drop:
                f.create_dataset(key, data=value)
    return path


def write_vlmaps_2d(scene, gs=30, d=8, seed=0, observed=0.35, version=1):
    """A ``<scene>/map/`` folder as VLMaps' 2023 create_lseg_map_batch writes it."""
    rng = np.random.default_rng(seed)
    folder = Path(scene) / "map"
    folder.mkdir(parents=True, exist_ok=True)
    seen = rng.random((gs, gs)) < observed
    k = int(seen.sum())
    grid = np.zeros((gs, gs, d), dtype=np.float32)
    grid[seen] = (rng.normal(size=(k, d)) * rng.uniform(0.5, 4, (k, 1))).astype(np.float32)
    color = np.zeros((gs, gs, 3), dtype=np.uint8)
    color[seen] = rng.integers(1, 256, (k, 3), dtype=np.uint8)
    gt = np.zeros((gs, gs), dtype=np.int32)
    gt[seen] = rng.integers(0, 4, k)
    obstacles = np.ones((gs, gs), dtype=np.uint8)
    obstacles[seen] = 0
    weight = seen.astype(float) * 3
    arrays = {
        f"grid_lseg_{version}.npy": grid,
        f"color_top_down_{version}.npy": color,
        f"grid_{version}_gt.npy": gt,
        f"weight_lseg_{version}.npy": weight,
        "obstacles.npy": obstacles,
    }
    for name, arr in arrays.items():
        with open(folder / name, "wb") as fh:
            np.save(fh, arr)
    return folder, {"grid": grid, "color": color, "gt": gt, "seen": seen}


# ---------------------------------------------------------------------------------------
# Builders that bin points the way VLMaps' own code does (re-implemented for these tests
# from the upstream formulas; see DESIGN.md "Facts learned in use"). They give the tests
# the true metric point behind every cell, independently of the adapters.


def upstream_base_pos2grid_id_3d(gs, cs, x, y, z):
    """VLMaps' scalar ``base_pos2grid_id_3d``: Python ``int`` truncates toward zero."""
    row = int(gs / 2 - int(x / cs))
    col = int(gs / 2 - int(y / cs))
    h = int(z / cs)
    return row, col, h


def upstream_grid_id2base_pos_3d(row, col, height, cs, gs):
    """VLMaps' ``grid_id2base_pos_3d``: the cell face nearest the origin."""
    return (gs / 2 - row) * cs, (gs / 2 - col) * cs, height * cs


def build_mobile_map(points, feats, rgb, gs=1000, cs=0.05, camera_height=1.5):
    """What ``VLMapBuilder.create_mobile_base_map`` leaves before ``save_3d_map``.

    Points (P, 3) are in the first base frame (x forward, y left, z up). Cells are
    allocated in first-hit order; later hits average (weight 1 each, the builder's alpha
    set to 1 for the tests). Out-of-range points are dropped as ``_out_of_range`` does.
    Returns the arrays truncated to ``max_id`` and the (P,) row of each point (-1 dropped).
    """
    vh = int(camera_height / cs)
    d = feats.shape[1]
    occupied = -np.ones((gs, gs, vh), dtype=np.int32)
    grid_feat = np.zeros((len(points), d), dtype=np.float32)
    grid_pos = np.zeros((len(points), 3), dtype=np.int32)
    weight = np.zeros(len(points), dtype=np.float32)
    grid_rgb = np.zeros((len(points), 3), dtype=np.uint8)
    row_of = np.full(len(points), -1, dtype=np.int64)
    max_id = 0
    for i, (x, y, z) in enumerate(np.asarray(points, dtype=np.float64)):
        row, col, h = upstream_base_pos2grid_id_3d(gs, cs, float(x), float(y), float(z))
        if not (0 <= row < gs and 0 <= col < gs and 0 <= h < vh):
            continue
        j = occupied[row, col, h]
        if j == -1:
            j = max_id
            occupied[row, col, h] = j
            grid_feat[j] = feats[i]
            grid_rgb[j] = rgb[i]
            weight[j] = 1.0
            grid_pos[j] = [row, col, h]
            max_id += 1
        else:
            w = weight[j]
            grid_feat[j] = (grid_feat[j] * w + feats[i]) / (w + 1)
            grid_rgb[j] = (grid_rgb[j].astype(np.float32) * w + rgb[i]) / (w + 1)
            weight[j] = w + 1
        row_of[i] = j
    return {
        "grid_feat": grid_feat[:max_id],
        "grid_pos": grid_pos[:max_id],
        "weight": weight[:max_id],
        "occupied_ids": occupied,
        "grid_rgb": grid_rgb[:max_id],
        "mapped_iter_list": list(range(5)),
    }, row_of


def save_3d_map(path, grid_feat, grid_pos, weight, occupied_ids, mapped_iter_list, grid_rgb=None):
    """Mirror of VLMaps' ``mapping_utils.save_3d_map``: one dataset per array, no casts
    except ``mapped_iter_list`` (int32), ``grid_rgb`` only when given."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.create_dataset("mapped_iter_list", data=np.array(mapped_iter_list, dtype=np.int32))
        f.create_dataset("grid_feat", data=grid_feat)
        f.create_dataset("grid_pos", data=grid_pos)
        f.create_dataset("weight", data=weight)
        f.create_dataset("occupied_ids", data=occupied_ids)
        if grid_rgb is not None:
            f.create_dataset("grid_rgb", data=grid_rgb)
    return path


def build_camera_map(points, feats, rgb, cs=0.05):
    """What ``VLMapBuilderCam.create_camera_map`` leaves before its ``save_3d_map``.

    ``pcd_min``/``pcd_max`` (float64) bound the cloud; ``occupied_ids`` has shape
    ``ceil((pcd_max - pcd_min) / cs + 1)``; a point's cell is
    ``[row, height, col] = round((p - pcd_min) / cs)`` (half to even). After the
    builder's reservation step ``weight`` is float64 and ``grid_rgb`` float32.
    """
    pts = np.asarray(points, dtype=np.float64)
    pcd_min, pcd_max = pts.min(axis=0), pts.max(axis=0)
    size = np.ceil((pcd_max - pcd_min) / cs + 1).astype(int)
    occupied = -np.ones(size, dtype=np.int32)
    d = feats.shape[1]
    grid_feat = np.zeros((len(pts), d), dtype=np.float32)
    grid_pos = np.zeros((len(pts), 3), dtype=np.int32)
    weight = np.zeros(len(pts), dtype=np.float64)
    grid_rgb = np.zeros((len(pts), 3), dtype=np.float32)
    row_of = np.full(len(pts), -1, dtype=np.int64)
    max_id = 0
    for i, p in enumerate(pts):
        row, height, col = np.round((p - pcd_min) / cs).astype(int)
        j = occupied[row, height, col]
        if j == -1:
            j = max_id
            occupied[row, height, col] = j
            grid_feat[j], grid_rgb[j], weight[j] = feats[i], rgb[i], 1.0
            grid_pos[j] = [row, height, col]
            max_id += 1
        else:
            w = weight[j]
            grid_feat[j] = (grid_feat[j] * w + feats[i]) / (w + 1)
            grid_rgb[j] = (grid_rgb[j] * w + rgb[i]) / (w + 1)
            weight[j] = w + 1
        row_of[i] = j
    return {
        "grid_feat": grid_feat[:max_id],
        "grid_pos": grid_pos[:max_id],
        "weight": weight[:max_id],
        "occupied_ids": occupied,
        "grid_rgb": grid_rgb[:max_id],
        "mapped_iter_list": list(range(3)),
        "pcd_min": pcd_min,
        "pcd_max": pcd_max,
        "cs": cs,
    }, row_of


def save_3d_map_cam(path, arrays):
    """Mirror of ``VLMapBuilderCam.save_3d_map``: the six arrays (``grid_rgb`` always),
    ``pcd_min``/``pcd_max`` and a scalar float64 ``cs`` dataset."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    cast = {"mapped_iter_list": lambda v: np.array(v, dtype=np.int32), "cs": np.float64}
    with h5py.File(path, "w") as f:
        for key in CAMERA_FIELDS:
            f.create_dataset(key, data=cast.get(key, np.asarray)(arrays[key]))
    return path


def upstream_pos2grid_id(gs, cs, xx, yy):
    """VLMaps 2023 ``pos2grid_id``, called with camera ``(x, z)``: returns ``(col, row)``."""
    x = int(gs / 2 + int(xx / cs))
    y = int(gs / 2 - int(yy / cs))
    return x, y


def upstream_grid_id2pos(gs, cs, x, y):
    """VLMaps 2023 ``grid_id2pos(gs, cs, col, row)``: camera ``(x, z)`` of the face
    nearest the origin."""
    xx = (x - gs / 2) * cs
    zz = (gs / 2 - y) * cs
    return xx, zz


def build_lseg_grid(points_xz, feats, gs=1000, cs=0.05):
    """What ``create_lseg_map_batch`` fuses into ``grid_lseg_1.npy`` and
    ``weight_lseg_1.npy``: a running mean per cell (float32 grid, float64 weights).
    Returns ``(grid, weight, cells)`` with the ``(row, col)`` of every point."""
    d = feats.shape[1]
    grid = np.zeros((gs, gs, d), dtype=np.float32)
    weight = np.zeros((gs, gs), dtype=float)
    cells = []
    for (x, z), f in zip(np.asarray(points_xz, dtype=np.float64), feats):
        col, row = upstream_pos2grid_id(gs, cs, float(x), float(z))
        if not (0 <= row < gs and 0 <= col < gs):
            cells.append((-1, -1))
            continue
        w = weight[row, col]
        grid[row, col] = (grid[row, col] * w + f) / (w + 1)
        weight[row, col] = w + 1
        cells.append((row, col))
    return grid, weight, np.asarray(cells, dtype=np.int64).reshape(-1, 2)


def save_lseg_folder(scene, grid, weight, color=None, gt=None, obstacles=None):
    """``<scene>/map/`` with ``np.save`` of each array, as ``save_map`` does."""
    folder = Path(scene) / "map"
    folder.mkdir(parents=True, exist_ok=True)
    np.save(folder / "grid_lseg_1.npy", grid)
    np.save(folder / "weight_lseg_1.npy", weight)
    gs = grid.shape[0]
    np.save(
        folder / "color_top_down_1.npy", np.zeros((gs, gs, 3), np.uint8) if color is None else color
    )
    np.save(folder / "grid_1_gt.npy", np.zeros((gs, gs), np.int32) if gt is None else gt)
    np.save(
        folder / "obstacles.npy", np.ones((gs, gs), np.uint8) if obstacles is None else obstacles
    )
    return folder
