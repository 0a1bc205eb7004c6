"""Fixture writers that follow VLMaps' own on-disk formats (written for these tests).

3D (``vlmaps/utils/mapping_utils.py::save_3d_map`` and ``VLMapBuilderCam.save_3d_map``):
datasets ``mapped_iter_list`` int32, ``grid_feat`` (N, D) float32, ``grid_pos`` (N, 3)
int32, ``weight`` (N,) float32, ``occupied_ids`` (gs, gs, vh) int32 (-1 empty, else row),
``grid_rgb`` (N, 3) uint8; camera-base files add ``pcd_min``/``pcd_max`` (3,) float64 and a
scalar ``cs``. 2D (``create_lseg_map_batch``): ``map/grid_lseg_1.npy`` (gs, gs, D) float32,
``color_top_down_1.npy`` (gs, gs, 3) uint8, ``grid_1_gt.npy`` (gs, gs) int32,
``obstacles.npy`` (gs, gs) uint8, ``weight_lseg_1.npy`` (gs, gs) float64.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import h5py
import numpy as np


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
