"""Pixel maps' frames: per-image masks and pixel coordinates of any items.

A pixel map (``kind: pixels``, e.g. from the ``image-features`` adapter) lists its
frames in ``LatentMap.frames``: item ``offset + y * W + x`` is pixel ``(x, y)`` of a frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import FrameInfo, LatentMap


def masks_per_frame(lmap: LatentMap | Sequence[FrameInfo], mask: Any) -> dict[str, np.ndarray]:
    """Split an ``(N,)`` item mask of a pixel map into ``{frame_id: (H, W) bool}``.

    ``lmap`` is the pixel map, or its frames: ``LatentMap.frames``,
    ``frames_from_npz(path)`` of a ``quash query --out RESULT.npz`` file or of a map
    ``quash convert`` wrote, or ``frames_from_zarr(path)`` of a ``--out RESULT.zarr``
    store or a zarr map.

    Examples
    --------
    >>> import numpy as np
    >>> from quash_plugins.core.types import FrameInfo, LatentMap
    >>> m = LatentMap(np.ones((6, 2), np.float32), kind="pixels",
    ...               frames=[FrameInfo("a", 1, 2, 0), FrameInfo("b", 2, 2, 2)])
    >>> masks_per_frame(m, np.array([1, 0, 0, 0, 0, 1], bool))["b"].tolist()
    [[False, False], [False, True]]
    >>> masks_per_frame(m.frames, np.array([1, 0, 0, 0, 0, 1], bool))["a"].tolist()
    [[True, False]]
    """
    if isinstance(lmap, LatentMap):
        frames, n, where = lmap.frames, lmap.n, lmap.source.get("path", "the map")
    else:
        frames = list(lmap) if lmap is not None else None
        n, where = sum(f.size for f in frames or ()), "these frames"
    if not frames:
        raise QuashError(
            f"{where} has no frames; per-image masks need a pixel map (e.g. read with the "
            "'image-features' adapter) or its frames (frames_from_npz or frames_from_zarr of a "
            "result file)."
        )
    mask = np.asarray(mask)
    if mask.shape != (n,):
        raise QuashError(f"mask must have shape ({n},); got {mask.shape}.")
    return {
        f.frame_id: mask[f.offset : f.offset + f.size].astype(bool).reshape(f.height, f.width)
        for f in frames
    }


def pixel_coordinates(lmap: LatentMap, indices: Any) -> np.ndarray:
    """``(k, 3)`` int64 ``(x, y, frame_index)`` of item ``indices`` of a pixel map."""
    if not lmap.frames:
        raise QuashError("pixel_coordinates needs a pixel map with frames.")
    idx = np.asarray(indices, dtype=np.int64).ravel()
    offsets = np.asarray([f.offset for f in lmap.frames], dtype=np.int64)
    widths = np.asarray([f.width for f in lmap.frames], dtype=np.int64)
    frame = np.searchsorted(offsets, idx, side="right") - 1
    local = idx - offsets[frame]
    y, x = np.divmod(local, widths[frame])
    return np.stack([x, y, frame], axis=1)
