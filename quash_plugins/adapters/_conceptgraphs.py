"""A small reader for ConceptGraphs ``*.pkl.gz`` maps, behind an explicit opt-in.

ConceptGraphs pickles a dict whose ``objects`` entry is a list of per-object dicts with
``clip_ft`` ``(D,)``, ``pcd_np`` ``(P, 3)`` and ``pcd_color_np`` ``(P, 3)`` in 0-1. Every
point of an object gets the object's feature, as in OpenLex3D's layout. Only reached
through ``openlex3d`` with ``allow_pickle=True``: unpickling runs code from the file.

Beside ``objects`` it saves ``bg_objects``: the background objects (wall, floor,
ceiling) that its mapping keeps apart when run with background classes, or None.
ConceptGraphs writes both with the same ``MapObjectList.to_serializable()``, so each
background object carries the same fields (``clip_ft``, ``pcd_np``, ``pcd_color_np``)
and is read the same way, after the objects (``background=True``, the default: they are
part of the map). ``background=False`` leaves them out, and says how many.
"""

from __future__ import annotations

import gzip
import logging
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.types import LatentMap, record_inputs
from ._rows import IndexedRows, colors_to_uint8

log = logging.getLogger(__name__)


def _as_numpy(value: Any) -> np.ndarray:
    if hasattr(value, "detach"):  # a torch tensor
        value = value.detach().cpu().numpy()
    return np.asarray(value)


def _background(data: dict, path: Path) -> list:
    """ConceptGraphs' ``bg_objects``: a list of object dicts, or None (no background
    classes); a dict of them (the form its mapping holds before saving) gives its
    values that are not None."""
    bg = data.get("bg_objects")
    if bg is None:
        return []
    if isinstance(bg, dict):
        return [v for v in bg.values() if v is not None]
    if isinstance(bg, (list, tuple)):
        return list(bg)
    raise MapFormatError(
        f"{path}: field 'bg_objects' must be a list of objects (or None); got "
        f"{type(bg).__name__}. Read the map without it with the option background=false."
    )


def _count_only(data: dict) -> list:
    """``bg_objects`` when it is left out: only counted, never checked."""
    bg = data.get("bg_objects")
    return (
        list(bg.values() if isinstance(bg, dict) else bg)
        if isinstance(bg, (list, tuple, dict))
        else []
    )


def read_conceptgraphs(path: Path, background: bool = True) -> LatentMap:
    """Read a trusted ConceptGraphs pickle into an object-indexed point map.

    ``objects`` first, then (``background``) ``bg_objects``: object ``i`` of the map's
    table is ``objects[i]``, and ``len(objects) + j`` is ``bg_objects[j]``.
    """
    if not isinstance(background, (bool, np.bool_)):
        raise MapFormatError(
            f"Adapter 'openlex3d': option 'background' must be true or false; got {background!r}."
        )
    opener = gzip.open if str(path).lower().endswith(".gz") else open
    try:
        with opener(path, "rb") as f:
            data = pickle.load(f)  # noqa: S301 - explicit opt-in (allow_pickle=True)
    except (OSError, EOFError, pickle.UnpicklingError, ModuleNotFoundError, AttributeError) as exc:
        raise MapFormatError(f"{path}: cannot unpickle ({type(exc).__name__}: {exc}).") from None
    objects = data.get("objects") if isinstance(data, dict) else None
    if not isinstance(objects, list):
        raise MapFormatError(f"{path}: field 'objects' is missing or empty (a ConceptGraphs map?).")
    bg = _background(data, path) if background else _count_only(data)
    if bg and not background:
        log.info(
            "%s: %d background objects (bg_objects: wall, floor, ceiling...) left out "
            "(background=false)",
            path,
            len(bg),
        )
    items = [("objects", i, obj) for i, obj in enumerate(objects)]
    if background:
        items += [("bg_objects", j, obj) for j, obj in enumerate(bg)]
    if not items:
        raise MapFormatError(f"{path}: field 'objects' is missing or empty (a ConceptGraphs map?).")
    feats, points, colors, index = [], [], [], []
    for row, (field, i, obj) in enumerate(items):
        if not isinstance(obj, dict):
            raise MapFormatError(
                f"{path}: {field}[{i}] is a {type(obj).__name__}, not an object's dict."
            )
        for key in ("clip_ft", "pcd_np"):
            if key not in obj:
                raise MapFormatError(f"{path}: {field}[{i}] has no field {key!r}.")
        ft = _as_numpy(obj["clip_ft"]).reshape(-1)
        pts = _as_numpy(obj["pcd_np"]).astype(np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise MapFormatError(f"{path}: {field}[{i}].pcd_np must be (P, 3); got {pts.shape}.")
        if feats and ft.shape != feats[0].shape:
            raise MapFormatError(
                f"{path}: {field}[{i}].clip_ft has shape {ft.shape}, not {feats[0].shape}."
            )
        feats.append(ft)
        points.append(pts)
        col = obj.get("pcd_color_np")
        colors.append(None if col is None else _as_numpy(col))
        index.append(np.full(len(pts), row, dtype=np.int64))
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
            {
                "adapter": "openlex3d",
                "path": str(path),
                "format": "conceptgraphs",
                "objects": len(objects),
                "background_objects": len(bg) if background else 0,
                "background_left_out": 0 if background else len(bg),
            }
        ),
    )
