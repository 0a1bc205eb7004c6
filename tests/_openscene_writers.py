"""Fixture writers that follow OpenScene's own save code (written for these tests).

- ``scripts/preprocess/preprocess_3d_scannet.py``: ``torch.save((coords, colors,
  labels), <scene>_vh_clean_2.pth)``: float64 coordinates (read through plyfile into
  ``np.array``), colours ``rgb / 127.5 - 1`` (float64), labels float64 with 255 = ignore.
  Matterport stores int64 labels, nuScenes a scalar ``0`` for the colours.
- ``scripts/feature_fusion/fusion_util.py::save_fused_feature``: for each of
  ``num_rand_file_per_scene`` files, a random subset of ``min(n_points, n_split_points)``
  points ANDed with the visible points gives ``mask_full`` (torch bool, N); the file
  ``<scene>_<n>.pt`` is ``torch.save({"feat": feat_bank[mask_full].half().cpu(),
  "mask_full": mask_full})``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _torch():
    import torch

    return torch


def preprocess_scannet(path, coords, rgb, labels):
    """ScanNet: ``(coords f64, rgb / 127.5 - 1 f64, labels f64 with 255 = ignore)``."""
    torch = _torch()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    coords = np.array([list(p) for p in np.asarray(coords)])  # as from plyfile rows
    colors = np.asarray(rgb, dtype=np.uint8) / 127.5 - 1
    torch.save((coords, colors, np.asarray(labels, dtype=np.float64)), path)
    return path


def preprocess_matterport(path, coords, rgb, labels):
    """Matterport: like ScanNet, but int64 labels (majority face vote)."""
    torch = _torch()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    colors = np.asarray(rgb, dtype=np.uint8) / 127.5 - 1
    torch.save((np.asarray(coords, np.float64), colors, np.asarray(labels, np.int64)), path)
    return path


def preprocess_nuscenes(path, coords, labels):
    """nuScenes: no colours (a scalar 0), float64 labels."""
    torch = _torch()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save((np.asarray(coords, np.float64), 0, np.asarray(labels, np.float64)), path)
    return path


def save_fused_feature(
    feat_bank,
    point_ids,
    n_points,
    out_dir,
    scene_id,
    num_rand_file_per_scene=1,
    n_split_points=2_000_000,
    seed=0,
):
    """Mirror of OpenScene's ``save_fused_feature``; returns the written paths.

    ``feat_bank`` is ``(n_points, D)`` (a torch tensor or numpy array), ``point_ids``
    the indices of the visible points.
    """
    torch = _torch()
    rng = np.random.default_rng(seed)
    feat_bank = torch.as_tensor(np.asarray(feat_bank, dtype=np.float32))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    visible = torch.zeros(n_points, dtype=torch.bool)
    visible[torch.as_tensor(np.asarray(point_ids, dtype=np.int64))] = True
    paths = []
    for n in range(num_rand_file_per_scene):
        rand_ind = rng.choice(n_points, min(n_points, n_split_points), replace=False)
        mask_entire = torch.zeros(n_points, dtype=torch.bool)
        mask_entire[torch.as_tensor(rand_ind)] = True
        mask_full = mask_entire & visible
        path = out_dir / f"{scene_id}_{n}.pt"
        torch.save({"feat": feat_bank[mask_full].half().cpu(), "mask_full": mask_full}, path)
        paths.append(path)
    return paths


def small_scannet_scene(root, n=40, d=8, seed=0, visible=None):
    """One small ScanNet scene, ``root/scannet_3d/val/scene0011_00_vh_clean_2.pth`` (labels
    0-2) and ``root/openseg/scene0011_00_0.pt`` (the points in ``visible``, default all);
    returns ``(pth, pt, coords, feat_bank)``."""
    rng = np.random.default_rng(seed)
    coords = rng.uniform(-2, 2, size=(n, 3))
    pth = preprocess_scannet(
        Path(root) / "scannet_3d" / "val" / "scene0011_00_vh_clean_2.pth",
        coords,
        rng.integers(0, 256, size=(n, 3)),
        rng.integers(0, 3, size=n).astype(np.float64),
    )
    feat_bank = rng.normal(size=(n, d))
    ids = np.arange(n) if visible is None else visible
    [pt] = save_fused_feature(feat_bank, ids, n, Path(root) / "openseg", "scene0011_00")
    return pth, pt, coords, feat_bank
