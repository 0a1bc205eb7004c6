"""Neighbourhoods of a map's items: connected components and grown regions.

:class:`MapTopology` serves the presence check (:mod:`quash_plugins.engine.presence`:
the components of a mask, a component's surroundings, growth through connected items)
and the evaluation (ground-truth segments, OpenLex3D's inverse rank). Voxels are
26-connected cells, points are linked within a radius, pixels are 8-connected within
one frame.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..core.types import LatentMap

#: Largest ``dilate`` (neighbourhood steps); a grown region beyond a few steps is no
#: longer the component's surroundings.
MAX_DILATE = 3
_OFFSETS26 = np.array(
    [d for d in itertools.product((-1, 0, 1), repeat=3)], dtype=np.int64
)  # includes (0, 0, 0)


def grid_cells(lmap: LatentMap) -> np.ndarray | None:
    """Integer voxel coordinates ``(N, 3)`` of every item, or None without a grid."""
    if lmap.grid_index is not None:
        return np.asarray(lmap.grid_index, dtype=np.int64)
    if lmap.kind == "voxels" and lmap.voxel_size and lmap.positions is not None:
        return np.floor(lmap.positions / float(lmap.voxel_size) + 0.5).astype(np.int64)
    return None


class MapTopology:
    """Neighbourhoods of a map's items: connected components and grown regions.

    ``kind`` is ``"voxels"`` (26-connected cells of ``grid_index``, or of positions on a
    voxel map with ``voxel_size``), ``"points"`` (positions linked within ``radius``:
    1.5 voxel sizes when known, else twice the 90th percentile of nearest-neighbour
    distances), ``"pixels"`` (8-connected pixels of one frame) or None (no neighbourhood).
    """

    def __init__(self, lmap: LatentMap) -> None:
        self.n = lmap.n
        self.kind: str | None = None
        self.why = ""
        cells = grid_cells(lmap)
        if lmap.kind == "pixels" and lmap.frames:
            self.kind = "pixels"
            self.frames = list(lmap.frames)
            self.frame_of = np.repeat(np.arange(len(self.frames)), [f.size for f in self.frames])
        elif cells is not None:
            self.kind = "voxels"
            pad = MAX_DILATE + 1
            lo = cells.min(axis=0) - pad if len(cells) else np.zeros(3, np.int64)
            self.span = (cells.max(axis=0) - lo + pad + 1) if len(cells) else np.ones(3, np.int64)
            self.key = self._key(cells - lo)
            self.lo = lo
            self.order = np.argsort(self.key, kind="stable")
            self.skey = self.key[self.order]
        elif lmap.positions is not None:
            from scipy.spatial import cKDTree

            from .instances import _default_radius

            self.kind = "points"
            self.pts = np.asarray(lmap.positions, dtype=np.float64)
            self.radius = float(_default_radius(lmap, self.pts)) if len(self.pts) else 1.0
            self.tree = cKDTree(self.pts) if len(self.pts) else None
        else:
            self.why = "the map has no voxel grid, positions or frames"

    def _key(self, c: np.ndarray) -> np.ndarray:
        s = self.span
        return (c[:, 0] * s[1] + c[:, 1]) * s[2] + c[:, 2]

    # -------------------------------------------------------------- components
    def labels(self, idx: np.ndarray) -> np.ndarray:
        """A component label for each item of ``idx`` (sorted item indices)."""
        if len(idx) == 0:
            return np.zeros(0, np.int64)
        if self.kind == "voxels":
            from .instances import _voxel_labels

            cells = self._cells_of(idx)
            return np.asarray(_voxel_labels(cells, 26), np.int64)
        if self.kind == "points":
            from .instances import _radius_labels

            return np.asarray(_radius_labels(self.pts[idx], self.radius, 65536), np.int64)
        if self.kind == "pixels":
            from scipy import ndimage

            out = np.zeros(len(idx), np.int64)
            nxt = 0
            fr = self.frame_of[idx]
            for f in np.unique(fr):
                frame = self.frames[int(f)]
                sel = np.flatnonzero(fr == f)
                local = idx[sel] - frame.offset
                img = np.zeros(frame.size, bool)
                img[local] = True
                lab, n = ndimage.label(
                    img.reshape(frame.height, frame.width), structure=np.ones((3, 3), bool)
                )
                out[sel] = lab.reshape(-1)[local] - 1 + nxt
                nxt += n
            return out
        return np.zeros(len(idx), np.int64)

    def _cells_of(self, idx: np.ndarray) -> np.ndarray:
        k = self.key[idx]
        s = self.span
        z = k % s[2]
        y = (k // s[2]) % s[1]
        x = k // (s[1] * s[2])
        return np.column_stack([x, y, z])

    def components(self, mask: np.ndarray) -> list[np.ndarray]:
        """The item indices of each connected component of ``mask``."""
        idx = np.flatnonzero(mask)
        if len(idx) == 0:
            return []
        lab = self.labels(idx)
        order = np.argsort(lab, kind="stable")
        lab_s = lab[order]
        starts = np.flatnonzero(np.r_[True, lab_s[1:] != lab_s[:-1]])
        return [idx[order[a:b]] for a, b in zip(starts, np.r_[starts[1:], len(idx)])]

    def pairs(self, members: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The neighbour pairs among ``members`` (sorted item indices), as positions in
        ``members`` ``(i, j)`` with ``i < j``: 26-connected voxels, points within the
        linking radius, 8-connected pixels of one frame."""
        n = len(members)
        empty = (np.zeros(0, np.int64), np.zeros(0, np.int64))
        if n < 2:
            return empty
        if self.kind == "voxels":
            keys = self.key[members]
            order = np.argsort(keys, kind="stable")
            skeys = keys[order]
            step = self._key(_OFFSETS26)
            rows, cols = [], []
            for d in step[step > 0]:  # each unordered pair once (and no self pair)
                pos = np.minimum(np.searchsorted(skeys, keys + d), n - 1)
                hit = skeys[pos] == keys + d
                rows.append(np.flatnonzero(hit))
                cols.append(order[pos[hit]])
            i, j = np.concatenate(rows), np.concatenate(cols)
        elif self.kind == "points":
            from scipy.spatial import cKDTree

            p = cKDTree(self.pts[members]).query_pairs(self.radius, output_type="ndarray")
            i, j = p[:, 0].astype(np.int64), p[:, 1].astype(np.int64)
        elif self.kind == "pixels":
            frame = self.frames[int(self.frame_of[members[0]])]
            local = members - frame.offset
            r, c = np.divmod(local, frame.width)
            rows, cols = [], []
            for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
                nb = (r + dr) * frame.width + (c + dc)
                ok = (r + dr < frame.height) & (c + dc >= 0) & (c + dc < frame.width)
                pos = np.minimum(np.searchsorted(local, nb), n - 1)
                hit = ok & (local[pos] == nb)
                rows.append(np.flatnonzero(hit))
                cols.append(pos[hit])
            i, j = np.concatenate(rows), np.concatenate(cols)
        else:
            return empty
        lo, hi = np.minimum(i, j), np.maximum(i, j)
        return lo, hi

    def region(self, members: np.ndarray, dilate: int) -> np.ndarray:
        """``members`` and every item within ``dilate`` neighbourhood steps of them."""
        if dilate <= 0 or len(members) == 0:
            return members
        if self.kind == "voxels":
            keys = self.key[members]
            step = self._key(_OFFSETS26)
            for _ in range(dilate):
                keys = np.unique((keys[:, None] + step[None, :]).reshape(-1))
            lo = np.searchsorted(self.skey, keys, "left")
            hi = np.searchsorted(self.skey, keys, "right")
            hit = hi > lo
            lo, hi = lo[hit], hi[hit]
            if not len(lo):
                return members
            counts = hi - lo
            pos = np.repeat(lo - np.r_[0, np.cumsum(counts)[:-1]], counts) + np.arange(
                int(counts.sum())
            )
            return np.unique(self.order[pos])
        if self.kind == "points":
            near = self.tree.query_ball_point(self.pts[members], r=self.radius * dilate)
            return np.unique(np.fromiter(itertools.chain.from_iterable(near), np.int64))
        if self.kind == "pixels":
            from scipy import ndimage

            frame = self.frames[int(self.frame_of[members[0]])]
            img = np.zeros(frame.size, bool)
            img[members - frame.offset] = True
            img = ndimage.binary_dilation(
                img.reshape(frame.height, frame.width),
                structure=np.ones((3, 3), bool),
                iterations=dilate,
            )
            return np.flatnonzero(img.reshape(-1)) + frame.offset
        return members

    def grow(
        self, keep: np.ndarray, candidates: np.ndarray, steps: int | None = None
    ) -> np.ndarray:
        """Hysteresis: ``keep`` plus each component of ``candidates`` that touches it, or,
        with ``steps``, the candidates at most that many neighbourhood steps from it."""
        if not keep.any():
            return keep
        if steps is not None:
            out = keep.copy()
            front = np.flatnonzero(keep)
            for _ in range(int(steps)):
                near = self.region(front, 1)
                near = near[candidates[near] & ~out[near]]
                if not len(near):
                    break
                out[near] = True
                front = near
            return out
        out = keep.copy()
        for members in self.components(candidates | keep):
            if keep[members].any():
                out[members] = True
        return out
