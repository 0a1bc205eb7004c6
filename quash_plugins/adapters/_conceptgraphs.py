"""A small reader for ConceptGraphs ``*.pkl.gz`` maps, behind an explicit opt-in.

ConceptGraphs pickles a dict whose ``objects`` entry is a list of per-object dicts with
``clip_ft`` ``(D,)``, ``pcd_np`` ``(P, 3)`` and ``pcd_color_np`` ``(P, 3)`` in 0-1. Every
point of an object gets the object's feature, as in OpenLex3D's layout. Only reached
through ``openlex3d`` with ``allow_pickle=True``: unpickling runs code from the file.
"""

from __future__ import annotations

import gzip
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.types import LatentMap, record_inputs
from ._rows import IndexedRows, colors_to_uint8


def _as_numpy(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def read_conceptgraphs(path: Path) -> LatentMap:
    """Read a trusted ConceptGraphs pickle into an object-indexed point map."""
    opener = gzip.open if str(path).lower().endswith(".gz") else open
    try:
        with opener(path, "rb") as f:
            data = pickle.load(f)  # noqa: S301 - explicit opt-in (allow_pickle=True)
    except (OSError, EOFError, pickle.UnpicklingError, ModuleNotFoundError, AttributeError) as exc:
        raise MapFormatError(f"{path}: cannot unpickle ({type(exc).__name__}: {exc}).") from None
    objects = data.get("objects") if isinstance(data, dict) else None
    if not isinstance(objects, list) or not objects:
        raise MapFormatError(f"{path}: field 'objects' is missing or empty (a ConceptGraphs map?).")
    feats, points, colors, index = [], [], [], []
    for i, obj in enumerate(objects):
        for key in ("clip_ft", "pcd_np"):
            if key not in obj:
                raise MapFormatError(f"{path}: objects[{i}] has no field {key!r}.")
        ft = _as_numpy(obj["clip_ft"]).reshape(-1)
        pts = _as_numpy(obj["pcd_np"]).astype(np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise MapFormatError(f"{path}: objects[{i}].pcd_np must be (P, 3); got {pts.shape}.")
        if feats and ft.shape != feats[0].shape:
            raise MapFormatError(
                f"{path}: objects[{i}].clip_ft has shape {ft.shape}, not {feats[0].shape}."
            )
        feats.append(ft)
        points.append(pts)
        col = obj.get("pcd_color_np")
        colors.append(None if col is None else _as_numpy(col))
        index.append(np.full(len(pts), i, dtype=np.int64))
    table = np.stack(feats).astype(np.float32)
    positions = np.concatenate(points)
    if not np.isfinite(table).all():
        raise MapFormatError(f"{path}: field 'clip_ft' contains NaN or Inf.")
    rgb = None
    if all(c is not None and c.shape == p.shape for c, p in zip(colors, points)):
        rgb = colors_to_uint8(np.concatenate(colors), str(path), "auto")
    return LatentMap(
        embeddings=IndexedRows(table, np.concatenate(index)),
        kind="points",
        positions=positions,
        colors=rgb,
        normalize=True,
        source=record_inputs(
            {"adapter": "openlex3d", "path": str(path), "format": "conceptgraphs"}
        ),
    )
