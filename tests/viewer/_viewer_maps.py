"""Small maps, a table encoder and Quash for the viewer tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from quash_plugins.core import registry
from quash_plugins.core.types import FrameInfo, LatentMap
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine.pipeline import Quash

#: 4-d text embeddings: chair and sofa are separable from the generic negatives.
TABLE = {
    "chair": [1.0, 0.0, 0.0, 0.0],
    "sofa": [0.0, 1.0, 0.0, 0.0],
    "other": [0.0, 0.0, 1.0, 0.0],
    "background": [0.0, 0.0, 0.0, 1.0],
    "nothing": [0.0, 0.0, 0.7, 0.7],
}


def make_quash() -> Quash:
    enc = TableEncoder(table=TABLE)
    return Quash(enc, classifier=registry.create("classifiers", "contrast"), cache=False)


def _labelled_embeddings(labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """chair -> axis 0, sofa -> axis 1, else axis 2/3, plus small noise.

    Every item leans a little towards "other", so an item that is not the query is
    closer to "other" than to the query (the contrast rule is then unambiguous).
    """
    emb = np.zeros((len(labels), 4), dtype=np.float32)
    emb[:, 2] = 0.3
    emb[labels == 0, 0] = 1.0
    emb[labels == 1, 1] = 1.0
    emb[labels == 2, 2] = 1.0
    emb[labels == 2, 3] = 0.3
    emb += rng.normal(0.0, 0.05, emb.shape).astype(np.float32)
    return emb


def _voxels(grid, labels, voxel, colors, rng, name: str) -> LatentMap:
    """A labelled voxel map of chair (0), sofa (1) and floor (2) cells."""
    return LatentMap(
        _labelled_embeddings(labels, rng),
        kind="voxels",
        positions=(grid * voxel).astype(np.float32),
        colors=colors,
        labels=labels,
        label_names=["chair", "sofa", "floor"],
        voxel_size=voxel,
        grid_index=grid,
        source={"adapter": "test", "path": name},
    )


def voxel_map(shape=(6, 5, 3), voxel=0.1, colors=True, seed=0) -> LatentMap:
    """A voxel map: a chair block, a sofa block and floor.

    ``colors``: True for random RGB, ``"gray"`` for grey levels, False for none.
    """
    rng = np.random.default_rng(seed)
    grid = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
    labels = np.full(len(grid), 2, dtype=np.int64)
    labels[(grid[:, 0] < 2) & (grid[:, 1] < 2)] = 0
    labels[(grid[:, 0] >= 4) & (grid[:, 1] >= 3)] = 1
    if colors == "gray":
        cols = np.repeat(rng.integers(60, 200, (len(grid), 1), dtype=np.uint8), 3, axis=1)
    elif colors:
        cols = rng.integers(0, 255, (len(grid), 3), dtype=np.uint8)
    else:
        cols = None
    return _voxels(grid, labels, voxel, cols, rng, "voxels.npz")


def pixel_map(n_frames=2, h=6, w=8, seed=1) -> LatentMap:
    """A per-image map without positions or colours (PCA colouring is used)."""
    rng = np.random.default_rng(seed)
    frames, labels = [], []
    for f in range(n_frames):
        lab = np.full((h, w), 2, dtype=np.int64)
        lab[1:3, 1 + f : 4 + f] = 0
        lab[4:, 5:] = 1
        labels.append(lab.ravel())
        frames.append(FrameInfo(f"frame {f:03d}", h, w, f * h * w))
    labels = np.concatenate(labels)
    return LatentMap(
        _labelled_embeddings(labels, rng),
        kind="pixels",
        labels=labels,
        label_names=["chair", "sofa", "floor"],
        frames=frames,
        source={"adapter": "test", "path": "pixels"},
    )


def write_table_config(directory: Path) -> Path:
    """A YAML config using a table encoder file and the contrast classifier."""
    table = directory / "table.npz"
    np.savez(
        table,
        texts=np.array(list(TABLE), dtype=str),
        embeddings=np.array(list(TABLE.values()), dtype=np.float32),
    )
    cfg = directory / "quash.yaml"
    cfg.write_text(
        "name: table-contrast\n"
        "encoder: {name: table, file: table.npz}\n"
        "classifier: {name: contrast}\n"
        "cache: false\n",
        encoding="utf-8",
    )
    return cfg


def room_map(voxel=0.25, size=(5.0, 4.0), height=2.5, seed=2) -> LatentMap:
    """One room as a scan sees it: floor, walls and ceiling voxels (surfaces only), with a
    chair block and a sofa block standing on the floor. Label 2 is "floor" (structure)."""
    rng = np.random.default_rng(seed)
    nx, ny, nz = (int(round(s / voxel)) + 1 for s in (*size, height))
    grid = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"), -1)
    grid = grid.reshape(-1, 3)
    x, y, z = grid.T
    shell = (x == 0) | (x == nx - 1) | (y == 0) | (y == ny - 1) | (z == 0) | (z == nz - 1)
    chair = (x >= 2) & (x <= 4) & (y >= 2) & (y <= 4) & (z >= 1) & (z <= 3)
    sofa = (x >= nx - 8) & (x <= nx - 3) & (y >= ny - 5) & (y <= ny - 3) & (z >= 1) & (z <= 2)
    keep = shell | chair | sofa
    grid = grid[keep]
    labels = np.full(len(grid), 2, dtype=np.int64)
    labels[chair[keep]] = 0
    labels[sofa[keep]] = 1
    cols = np.repeat(rng.integers(90, 190, (len(grid), 1), dtype=np.uint8), 3, axis=1)
    return _voxels(grid, labels, voxel, cols, rng, "room.npz")
