"""Connected groups of matched items: what a robot navigates to.

:func:`find_instances` groups the matched items of a :class:`~quash_plugins.core.types.LatentMap`
according to its kind:

* **voxels** (``grid_index`` given, or derived as ``round(positions / voxel_size)``):
  face/edge/corner connectivity on the integer grid (26 neighbours by default; 18 or 6
  on request). Neighbours are found by sorting the matched cells' integer keys and
  binary-searching half of the neighbour offsets, so the cost is
  ``O(m log m)`` in the number ``m`` of matched items, whatever N is.
* **points**: single-linkage grouping within ``radius`` metres (the DBSCAN clusters with
  ``min_samples=1``), built from a KD-tree in chunks of ``chunk`` points and merged by
  repeated label contraction so that memory stays bounded; ``method="dbscan"`` runs
  scikit-learn's DBSCAN with ``min_samples`` instead (noise points are dropped).
* **pixels**: 8- (or 4-) connected pixels within each frame (``lmap.frames``); each
  instance carries its ``frame_id``.

Each :class:`~quash_plugins.core.types.Instance` has the item ``indices`` (into the map),
``centroid``, ``bbox_min``/``bbox_max`` (metres when the map has positions; for pixel maps
without positions, pixel coordinates ``(x=col, y=row, 0)``), the item count and the mean
score. Instances are sorted by size (largest first) and numbered in that order.

Examples
--------
>>> import numpy as np
>>> from quash_plugins.core.types import LatentMap
>>> grid = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 1], [5, 5, 5], [5, 5, 6], [5, 6, 6]])
>>> m = LatentMap(np.ones((6, 2), np.float32), kind="voxels", grid_index=grid, voxel_size=0.1,
...               positions=(grid * 0.1).astype(np.float32))
>>> inst = find_instances(m, np.ones(6, bool), np.ones(6, np.float32))
>>> [i.size for i in inst], [round(float(x), 3) for x in inst[0].centroid]
([3, 3], [0.0, 0.033, 0.067])
"""

from __future__ import annotations

import itertools
import logging
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.types import Instance, LatentMap

log = logging.getLogger(__name__)

OPTIONS = ("method", "connectivity", "radius", "min_samples", "min_size", "max_instances", "chunk")
METHODS = ("auto", "voxels", "radius", "dbscan", "pixels", "none")


def find_instances(
    lmap: LatentMap, mask: np.ndarray, scores: np.ndarray, **options: Any
) -> list[Instance]:
    """Group the matched items of ``lmap`` into instances.

    Parameters
    ----------
    lmap
        The map the mask refers to.
    mask
        ``(N,)`` bool, the matched items.
    scores
        ``(N,)`` float scores; each instance reports the mean over its items.
    method
        ``"auto"`` (by map kind), ``"voxels"``, ``"radius"``, ``"dbscan"``, ``"pixels"``
        or ``"none"``.
    connectivity
        Voxels: 26 (default), 18 or 6. Pixels: 8 (default) or 4.
    radius
        Point maps: linking distance in metres. Default: ``1.5 * voxel_size`` when known,
        else twice the 90th percentile of the matched points' nearest-neighbour distances.
    min_samples
        DBSCAN only: neighbours needed for a core point (default 3).
    min_size
        Groups with fewer items are dropped (default 3).
    max_instances
        Keep at most this many of the largest groups (default 100; None for all).
    chunk
        Points per KD-tree query chunk (bounds memory; default 65536).

    Returns
    -------
    list[Instance]
        Sorted by size, largest first.
    """
    unknown = set(options) - set(OPTIONS)
    if unknown:
        raise ConfigError(
            f"instances does not accept {sorted(unknown)}; it takes {', '.join(OPTIONS)}."
        )
    method = options.get("method", "auto")
    if method not in METHODS:
        raise ConfigError(f"instances.method must be one of {METHODS}; got {method!r}.")
    min_size = max(1, int(options.get("min_size", 3)))
    max_instances = options.get("max_instances", 100)
    mask = np.asarray(mask, dtype=bool).reshape(-1)
    if len(mask) != lmap.n:
        raise ConfigError(f"mask has {len(mask)} entries but the map has {lmap.n} items.")
    scores = np.asarray(scores, dtype=np.float32).reshape(-1)
    idx = np.flatnonzero(mask)
    if method == "none" or len(idx) < min_size:
        return []
    if method == "auto":
        method = _auto_method(lmap)
        if method is None:
            return []
    if method == "pixels":
        groups = _pixel_groups(lmap, mask, options.get("connectivity", 8))
    else:
        if method == "voxels":
            cells = _cells(lmap, idx)
            if cells is None:
                raise ConfigError("instances.method 'voxels' needs grid_index or voxel_size.")
            labels = _voxel_labels(cells, int(options.get("connectivity", 26)))
        else:
            if lmap.positions is None:
                raise ConfigError(f"instances.method {method!r} needs map positions.")
            pts = lmap.positions[idx].astype(np.float64)
            radius = options.get("radius") or _default_radius(lmap, pts)
            if method == "dbscan":
                labels = _dbscan_labels(pts, float(radius), int(options.get("min_samples", 3)))
            else:
                labels = _radius_labels(pts, float(radius), int(options.get("chunk", 65536)))
        groups = [(None, idx, labels)]
    return _summarise(lmap, groups, scores, min_size, max_instances)


def _auto_method(lmap: LatentMap) -> str | None:
    if lmap.kind == "pixels" and lmap.frames:
        return "pixels"
    if lmap.kind == "voxels" and (
        lmap.grid_index is not None or (lmap.voxel_size and lmap.positions is not None)
    ):
        return "voxels"
    if lmap.positions is not None:
        return "radius"
    return None


# ---------------------------------------------------------------------- voxels
def _cells(lmap: LatentMap, idx: np.ndarray) -> np.ndarray | None:
    if lmap.grid_index is not None:
        return np.asarray(lmap.grid_index[idx], dtype=np.int64)
    if lmap.voxel_size and lmap.positions is not None:
        return np.floor(lmap.positions[idx] / float(lmap.voxel_size) + 0.5).astype(np.int64)
    return None


def _offsets(connectivity: int) -> list[tuple[int, int, int]]:
    if connectivity not in (6, 18, 26):
        raise ConfigError(f"voxel connectivity must be 6, 18 or 26; got {connectivity}.")
    out = []
    for d in itertools.product((-1, 0, 1), repeat=3):
        nonzero = sum(abs(x) for x in d)
        if (
            nonzero == 0
            or (connectivity == 6 and nonzero > 1)
            or (connectivity == 18 and nonzero > 2)
        ):
            continue
        if d > (0, 0, 0):  # half of the symmetric offsets is enough for undirected edges
            out.append(d)
    return out


def _voxel_labels(cells: np.ndarray, connectivity: int) -> np.ndarray:
    """Connected-component label per cell (duplicate cells share a label)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = len(cells)
    lo = cells.min(axis=0) - 1
    span = cells.max(axis=0) - lo + 2
    c = cells - lo
    key = (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    rows, cols = [], []
    # identical cells (several items in one voxel) are connected too
    same = np.flatnonzero(skey[1:] == skey[:-1])
    rows.append(order[same])
    cols.append(order[same + 1])
    for d in _offsets(connectivity):
        nkey = key + (d[0] * span[1] + d[1]) * span[2] + d[2]
        pos = np.searchsorted(skey, nkey)
        pos_c = np.minimum(pos, m - 1)
        hit = skey[pos_c] == nkey
        rows.append(np.flatnonzero(hit))
        cols.append(order[pos_c[hit]])
    r = np.concatenate(rows)
    cidx = np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), dtype=np.int8), (r, cidx)), shape=(m, m)).tocsr()
    _, labels = connected_components(graph, directed=False)
    return labels


# ---------------------------------------------------------------------- points
def _default_radius(lmap: LatentMap, pts: np.ndarray) -> float:
    if lmap.voxel_size:
        return 1.5 * float(lmap.voxel_size)
    from scipy.spatial import cKDTree

    sample = (
        pts
        if len(pts) <= 20000
        else pts[np.random.default_rng(0).choice(len(pts), 20000, replace=False)]
    )
    if len(sample) < 2:
        return 1.0
    dist, _ = cKDTree(pts).query(sample, k=2)
    nn = dist[:, 1]
    nn = nn[nn > 0]
    return float(2.0 * np.percentile(nn, 90)) if nn.size else 1e-6


def _radius_labels(pts: np.ndarray, radius: float, chunk: int) -> np.ndarray:
    """Single-linkage components of the ``radius`` graph, built chunk by chunk."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    m = len(pts)
    tree = cKDTree(pts)
    labels = np.arange(m)
    chunk = max(1, chunk)
    for start in range(0, m, chunk):
        part = np.arange(start, min(m, start + chunk))
        neigh = tree.query_ball_point(pts[part], r=radius, return_sorted=False)
        counts = np.fromiter((len(x) for x in neigh), dtype=np.int64, count=len(part))
        if counts.sum() == len(part):
            continue  # only self-neighbours
        src = np.repeat(part, counts)
        dst = np.fromiter(
            itertools.chain.from_iterable(neigh), dtype=np.int64, count=int(counts.sum())
        )
        # contract: connect the current labels of both ends, then relabel everything
        a, b = labels[src], labels[dst]
        g = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(m, m)).tocsr()
        _, comp = connected_components(g, directed=False)
        labels = comp[labels]
    return labels


def _dbscan_labels(pts: np.ndarray, radius: float, min_samples: int) -> np.ndarray:
    from sklearn.cluster import DBSCAN

    return DBSCAN(eps=radius, min_samples=max(1, min_samples)).fit(pts).labels_


# ---------------------------------------------------------------------- pixels
def _pixel_groups(lmap: LatentMap, mask: np.ndarray, connectivity: int):
    from scipy import ndimage

    if connectivity not in (4, 8):
        raise ConfigError(f"pixel connectivity must be 4 or 8; got {connectivity}.")
    if not lmap.frames:
        raise ConfigError("instances.method 'pixels' needs a pixel map with frames.")
    structure = ndimage.generate_binary_structure(2, 2 if connectivity == 8 else 1)
    groups = []
    for frame in lmap.frames:
        sub = mask[frame.offset : frame.offset + frame.size]
        if not sub.any():
            continue
        lab, _ = ndimage.label(sub.reshape(frame.height, frame.width), structure=structure)
        flat = lab.reshape(-1)
        local = np.flatnonzero(flat)
        groups.append((frame, local + frame.offset, flat[local]))
    return groups


# ---------------------------------------------------------------------- summary
def _summarise(lmap, groups, scores, min_size, max_instances) -> list[Instance]:
    found = []
    for frame, items, labels in groups:
        keep = labels >= 0  # DBSCAN marks noise with -1
        items, labels = items[keep], labels[keep]
        if not len(items):
            continue
        order = np.argsort(labels, kind="stable")
        items, labels = items[order], labels[order]
        starts = np.flatnonzero(np.r_[True, labels[1:] != labels[:-1]])
        sizes = np.diff(np.r_[starts, len(labels)])
        big = sizes >= min_size
        if not big.any():
            continue
        coords = _coords(lmap, items, frame)
        sums = np.add.reduceat(coords, starts, axis=0)
        mins = np.minimum.reduceat(coords, starts, axis=0)
        maxs = np.maximum.reduceat(coords, starts, axis=0)
        ssum = np.add.reduceat(scores[items].astype(np.float64), starts)
        for k in np.flatnonzero(big):
            sl = slice(starts[k], starts[k] + sizes[k])
            found.append(
                (
                    int(sizes[k]),
                    items[sl],
                    sums[k] / sizes[k],
                    mins[k],
                    maxs[k],
                    ssum[k] / sizes[k],
                    frame.frame_id if frame is not None else None,
                )
            )
    found.sort(key=lambda g: (-g[0], int(g[1][0])))
    if max_instances is not None:
        found = found[: max(0, int(max_instances))]
    return [
        Instance(
            id=i,
            indices=np.sort(g[1]),
            centroid=g[2].astype(np.float32),
            bbox_min=g[3].astype(np.float32),
            bbox_max=g[4].astype(np.float32),
            mean_score=float(g[5]),
            frame_id=g[6],
        )
        for i, g in enumerate(found)
    ]


def _coords(lmap: LatentMap, items: np.ndarray, frame) -> np.ndarray:
    """``(m, 3)`` float64 positions of ``items`` (pixel ``(col, row, 0)`` without positions)."""
    if lmap.positions is not None:
        return lmap.positions[items].astype(np.float64)
    if frame is not None:
        local = items - frame.offset
        row, col = np.divmod(local, frame.width)
        return np.column_stack([col, row, np.zeros_like(row)]).astype(np.float64)
    if lmap.grid_index is not None:
        return lmap.grid_index[items].astype(np.float64)
    return np.column_stack([items, np.zeros_like(items), np.zeros_like(items)]).astype(np.float64)
