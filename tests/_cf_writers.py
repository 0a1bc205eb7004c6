"""Fixture writers following the upstream formats (written for these tests, not the adapters').

- ConceptFusion / gradslam ``Pointclouds.save_to_h5(save_dest)``: ``save_dest/pointclouds/``
  with ``pc_points.h5`` etc., each ``h5py.File(..., "w").create_dataset(<stem>, data=...)``.
- ConceptFusion ``extract_conceptfusion_features.py``: ``saved-feat/<stem>.pt`` =
  ``torch.save(tensor (H, W, D) float16)``; LSeg/DINO: ``torch.save(tensor (1, D, h, w))``.
- OpenLex3D predictions: ``point_cloud.pcd`` + ``embeddings.npy`` + ``index.npy``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

WORDS = ["chair", "sofa", "table", "lamp", "other", "background", "nothing"]


def tree_hash(root: Path) -> str:
    """One digest over every file name and content under ``root`` (or of one file)."""
    root = Path(root)
    h = hashlib.sha256()
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    for p in files:
        h.update(str(p.relative_to(root.parent)).encode())
        h.update(p.read_bytes())
    return h.hexdigest()


def text_table(tmp: Path, dim: int, seed: int = 1) -> tuple[Path, dict[str, np.ndarray]]:
    """An orthonormal-ish text table (npz for the ``table`` encoder) and its vectors."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(dim, dim)))
    vecs = {w: q[i % dim].astype(np.float32) for i, w in enumerate(WORDS)}
    path = tmp / "text.npz"
    np.savez(path, texts=np.asarray(WORDS), embeddings=np.stack([vecs[w] for w in WORDS]))
    return path, vecs


def contrast_config(tmp: Path, table: Path) -> Path:
    cfg = tmp / "contrast.yaml"
    cfg.write_text(
        "name: contrast\n"
        f"encoder: {{name: table, file: {table.name}}}\n"
        "heuristic: none\n"
        "negatives: [other, background, nothing]\n"
        "classifier: contrast\n"
        "cache: false\n"
    )
    return cfg


def save_pointclouds(save_dest: Path, **arrays: np.ndarray) -> Path:
    """gradslam's save_to_h5: one file per attribute, dataset named after the file."""
    import h5py

    folder = Path(save_dest) / "pointclouds"
    folder.mkdir(parents=True, exist_ok=True)
    for key, value in arrays.items():
        with h5py.File(f"{folder}/{key}.h5", "w") as f:
            f.create_dataset(key, data=value)
    return folder


def cf_arrays(n=80, d=16, seed=0, dtype=np.float16, zero_every=5, vecs=None, chair_rows=()):
    """Arrays of a ConceptFusion map: unnormalised embeddings, zero rows, colours 0-255."""
    rng = np.random.default_rng(seed)
    emb = rng.normal(size=(n, d)) * rng.uniform(0.5, 20.0, size=(n, 1))
    if vecs is not None:
        emb = np.tile(vecs["other"], (n, 1)) * 7.0 + 0.05 * rng.normal(size=(n, d))
        for r in chair_rows:
            emb[r] = vecs["chair"] * 3.0
    if zero_every:
        emb[::zero_every] = 0
    return {
        "pc_points": rng.uniform(-3, 3, size=(n, 3)).astype(np.float32),
        "pc_colors": rng.uniform(0, 255, size=(n, 3)).astype(np.float32),
        "pc_embeddings": emb.astype(dtype),
        "pc_features": rng.normal(size=(n, 3)).astype(np.float32),
        "pc_confidences": rng.uniform(size=(n, 1)).astype(np.float32),
    }


def save_feat_pt(folder: Path, stem: str, feat: np.ndarray) -> Path:
    """ConceptFusion's per-frame save: torch.save of a bare CPU tensor."""
    import torch

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{stem}.pt"
    torch.save(torch.from_numpy(np.ascontiguousarray(feat)), path)
    return path


def save_png(path: Path, rgb: np.ndarray) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(rgb).save(path)
    return path


def save_openlex3d(folder: Path, points, colors01, embeddings, index) -> Path:
    import open3d as o3d

    folder.mkdir(parents=True, exist_ok=True)
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    if colors01 is not None:
        pcd.colors = o3d.utility.Vector3dVector(np.asarray(colors01, dtype=np.float64))
    o3d.io.write_point_cloud(str(folder / "point_cloud.pcd"), pcd)
    np.save(folder / "embeddings.npy", embeddings)
    np.save(folder / "index.npy", index)
    return folder
