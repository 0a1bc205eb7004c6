"""Helpers shared by the VLMaps adapters (3D file, 2D grids, live object); their
``gs``/``cs``/``positions`` options are read and checked in :mod:`._vlmaps_options`.

Grid conventions, from VLMaps' own ``vlmaps/utils/mapping_utils.py`` and its builders:

* mobile-base 3D maps store ``grid_pos`` as ``[row, col, height]``. The builder bins a
  point ``(x, y, z)`` of the first base frame (x forward, y left, z up) with
  ``row = int(gs/2 - int(x/cs))``, ``col = int(gs/2 - int(y/cs))``, ``h = int(z/cs)``;
  Python's ``int`` truncates toward zero. Upstream's inverse ``grid_id2base_pos_3d``
  returns ``x = (gs/2 - row) * cs``, ``y = (gs/2 - col) * cs``, ``z = h * cs``: the face
  of the cell nearest the origin, not its centre.
* camera-base 3D maps store ``pcd_min`` and ``cs``, and bin with
  ``grid_pos = round((p - pcd_min) / cs)`` per axis, so ``p = pcd_min + grid_pos * cs``
  is both the exact inverse and the cell centre. ``p`` is in the camera poses' world
  frame, and the cell is ``[row, height, col]`` (``occupied_ids[row, height, col]``): the
  builder's top-down image keeps, per ``(row, col)``, the point of largest ``height``, so
  axis 1 is the height axis and the map is y-up (:data:`UP_AXIS`).
* 2023 top-down grids bin the first camera frame's ``(x, z)`` (x right, z forward) with
  ``col = int(gs/2 + int(x/cs))``, ``row = int(gs/2 - int(z/cs))``; upstream's inverse
  ``grid_id2pos`` again returns the face nearest the origin.

Because truncation toward zero folds ``(-cs, cs)`` into one index, the cell at the
origin index is two cells wide (centre 0), and every other cell's centre lies half a
cell further from the origin than upstream's inverse: ``(k + 0.5 * sign(k)) * cs`` for
the signed cell count ``k`` from the origin index ``gs // 2``. :func:`cell_centres`
computes that (``positions="centre"``, the default of every VLMaps adapter);
``positions="upstream"`` reproduces upstream's inverse functions exactly.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.maps import memmap_ref, open_memmap_ref

log = logging.getLogger(__name__)

POSE_TYPES = ("auto", "mobile_base", "camera_base")
#: The up axis of each pose type's positions (``LatentMap.source["up"]``): mobile-base
#: cells are ``[row, col, height]`` in the base frame (z up); camera-base cells are
#: ``[row, height, col]`` in the camera poses' frame (y up).
UP_AXIS = {"mobile_base": "+z", "camera_base": "+y"}


def cell_centres(k: np.ndarray, cs: float) -> np.ndarray:
    """Metres of the centre of signed cell offsets ``k`` from the origin cell.

    ``int()`` truncation bins ``(k * cs, (k + 1) * cs)`` into ``k > 0``,
    ``((k - 1) * cs, k * cs)`` into ``k < 0`` and ``(-cs, cs)`` into ``k = 0``, so the
    centre is ``(k + 0.5 * sign(k)) * cs``.
    """
    k = np.asarray(k, dtype=np.float64)
    return (k + 0.5 * np.sign(k)) * float(cs)


def mobile_base_positions(
    grid_pos: np.ndarray, gs: float, cs: float, positions: str = "centre"
) -> np.ndarray:
    """``(N, 3)`` float32 metres from VLMaps mobile-base ``[row, col, height]`` cells.

    ``positions="centre"``: cell centres (origin index ``gs // 2``; height 0 is the
    two-cell-wide cell around the floor, centre 0). ``"upstream"``:
    ``grid_id2base_pos_3d``: ``x = (gs/2 - row) * cs``, ``y = (gs/2 - col) * cs``,
    ``z = height * cs``.
    """
    g = np.asarray(grid_pos, dtype=np.float64).reshape(-1, 3)
    out = np.empty((len(g), 3), dtype=np.float64)
    if positions == "upstream":
        out[:, 0] = (gs / 2.0 - g[:, 0]) * cs
        out[:, 1] = (gs / 2.0 - g[:, 1]) * cs
        out[:, 2] = g[:, 2] * cs
    else:
        origin = float(int(gs) // 2)
        out[:, 0] = cell_centres(origin - g[:, 0], cs)
        out[:, 1] = cell_centres(origin - g[:, 1], cs)
        out[:, 2] = cell_centres(g[:, 2], cs)
    return out.astype(np.float32)


def camera_base_positions(grid_pos: np.ndarray, pcd_min: np.ndarray, cs: float) -> np.ndarray:
    """``(N, 3)`` float32 metres from VLMaps camera-base cells: ``pcd_min + grid_pos * cs``.

    The builder rounds ``(p - pcd_min) / cs``, so this is the exact inverse and the cell
    centre at once.
    """
    g = np.asarray(grid_pos, dtype=np.float64).reshape(-1, 3)
    return (np.asarray(pcd_min, dtype=np.float64).reshape(1, 3) + g * float(cs)).astype(np.float32)


def rgb_to_uint8(rgb: Any, where: str, field: str = "grid_rgb") -> np.ndarray:
    """VLMaps colours (uint8, or float 0-255 after weighted averaging) as uint8."""
    arr = np.asarray(rgb)
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype.kind not in "fiu":
        raise MapFormatError(f"{where}: field {field!r} must hold numbers; got dtype {arr.dtype}.")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise MapFormatError(f"{where}: field {field!r} contains NaN or Inf.")
    return np.clip(np.rint(arr), 0, 255).astype(np.uint8)


def load_label_names(spec: Any, where: str = "label_names") -> list[str] | None:
    """Label names from a file or an in-memory object.

    Accepted: ``None``; a list/tuple of names (index = label id); a mapping
    ``{id: name}``; a path to ``.txt`` (one name per line, or VLMaps'
    ``obj2cls_dict.txt`` lines ``obj_id: cls_id, name``), ``.yaml``/``.yml`` or ``.json``
    holding a list or a mapping. Missing ids in a mapping become ``"label_<id>"``.
    """
    if spec is None:
        return None
    if isinstance(spec, (str, Path)):
        return _names_from_file(Path(spec).expanduser())
    if isinstance(spec, Mapping):
        return _names_from_mapping(spec, where)
    if isinstance(spec, (Sequence, np.ndarray)):
        return [str(x) for x in spec]
    raise MapFormatError(
        f"{where}: expected a file path, a list of names or a mapping {{id: name}}; "
        f"got {type(spec).__name__}."
    )


def _names_from_mapping(mapping: Mapping[Any, Any], where: str) -> list[str]:
    try:
        items = {int(k): str(v) for k, v in mapping.items()}
    except (TypeError, ValueError):
        raise MapFormatError(
            f"{where}: a label mapping must be {{integer id: name}}; got keys {list(mapping)[:5]}."
        ) from None
    if not items:
        return []
    if min(items) < 0:
        raise MapFormatError(f"{where}: label ids must be >= 0; got {min(items)}.")
    return [items.get(i, f"label_{i}") for i in range(max(items) + 1)]


def _names_from_file(path: Path) -> list[str]:
    if not path.is_file():
        raise MapFormatError(f"Label-name file not found: {path}. Check the 'label_names' option.")
    text = path.read_text(encoding="utf-8")
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml", ".json"):
        try:
            if suffix == ".json":
                data = json.loads(text)
            else:
                from ..core.yaml_files import load_yaml_text

                data = load_yaml_text(text, str(path))
        except Exception as exc:  # noqa: BLE001 - any parse error is a format error
            raise MapFormatError(f"{path}: cannot parse label names ({exc}).") from None
        if isinstance(data, Mapping):
            return _names_from_mapping(data, str(path))
        if isinstance(data, list):
            return [str(x) for x in data]
        raise MapFormatError(f"{path}: expected a list of names or a mapping {{id: name}}.")
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if lines and all(_is_obj2cls_line(ln) for ln in lines):
        mapping = {}
        for ln in lines:
            _, rest = ln.split(":", 1)
            cls_id, name = rest.split(",", 1)
            mapping[int(cls_id.strip())] = name.strip()
        return _names_from_mapping(mapping, str(path))
    return lines


def _is_obj2cls_line(line: str) -> bool:
    if ":" not in line:
        return False
    head, rest = line.split(":", 1)
    if "," not in rest:
        return False
    try:
        int(head.strip())
        int(rest.split(",", 1)[0].strip())
    except ValueError:
        return False
    return True


def find_obj2cls(start: Path, levels: int = 2) -> Path | None:
    """VLMaps' ``obj2cls_dict.txt`` in ``start`` or up to ``levels`` parents, if any."""
    here = start if start.is_dir() else start.parent
    for _ in range(levels + 1):
        cand = here / "obj2cls_dict.txt"
        if cand.is_file():
            return cand
        here = here.parent
    return None


def check_labels(labels: Any, n: int, where: str, field: str) -> np.ndarray:
    """``(N,)`` int64 ground truth from ``(N,)`` or ``(N, 1)`` integer data."""
    arr = np.asarray(labels)
    if arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.ndim != 1 or len(arr) != n:
        raise MapFormatError(
            f"{where}: field {field!r} must have shape (N,) with N = {n} rows; got {arr.shape}."
        )
    if arr.dtype.kind == "f":
        if not np.isfinite(arr).all() or not np.array_equal(arr, np.rint(arr)):
            raise MapFormatError(f"{where}: field {field!r} must hold integer class ids.")
    elif arr.dtype.kind not in "iu":
        raise MapFormatError(f"{where}: field {field!r} must hold integers; got {arr.dtype}.")
    return arr.astype(np.int64)


def fit_label_names(
    names: list[str] | None,
    labels: np.ndarray | None,
    names_from: Any = None,
    labels_from: Any = None,
) -> list[str] | None:
    """Pad ``names`` with ``label_<id>`` so every label id in ``labels`` has a name.

    ``names_from`` (the ``label_names`` spec: a file is named in the warning) and
    ``labels_from`` (the file the labels were read from) only word the warning.
    """
    if names is None or labels is None or labels.size == 0:
        return names
    top = int(labels.max())
    if top >= len(names):
        given = (
            f"in {Path(names_from).expanduser()}; add the missing names to that file "
            "(index = label id)"
            if isinstance(names_from, (str, Path))
            else "in the label_names option; give one name per label id"
        )
        log.warning(
            "label ids%s reach %d but only %d label names were given %s; padding with "
            "label_<id> for ids %d to %d",
            f" in {labels_from}" if labels_from else "",
            top,
            len(names),
            given,
            len(names),
            top,
        )
        names = [*names, *(f"label_{i}" for i in range(len(names), top + 1))]
    return names


#: What to do about NaN/Inf rows in a map file (its adapter takes ``check_finite``): the
#: ``fix`` of :func:`~quash_plugins.adapters._rows.scan_finite` for VLMaps' files.
FINITE_FIX = "Fix or drop those rows, or pass check_finite=False to defer the check."


class RowSubset:
    """A lazy ``(len(index), D)`` view of ``base[index]`` for a 2-D array-like ``base``.

    Used to keep only the observed cells of a memory-mapped grid without loading it:
    slicing reads just the selected rows. Supports ``shape``, ``dtype``, ``ndim``,
    ``len``, ``__getitem__`` (slices, integer arrays, boolean masks, ``(rows, cols)``
    tuples) and ``__array__``.
    """

    def __init__(self, base: Any, index: np.ndarray) -> None:
        self.base = base
        self.index = np.asarray(index, dtype=np.int64)
        self.dtype = np.dtype(base.dtype)
        self.shape = (len(self.index), int(base.shape[1]))
        self.ndim = 2

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: Any) -> np.ndarray:
        cols: Any = slice(None)
        if isinstance(key, tuple):
            key, cols = (key + (slice(None),))[:2]
        rows = self.index[key]
        if np.ndim(rows) == 0:
            return np.asarray(self.base[int(rows)])[cols]
        return np.asarray(self.base[rows])[:, cols]

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self[:]
        return out if dtype is None else out.astype(dtype, copy=False)

    def __getstate__(self) -> dict[str, Any]:
        """Pickle a file-backed memory map by reference (for dask workers), not by value."""
        ref = memmap_ref(self.base)  # a reshaped grid too (with its own offset)
        if ref is not None:
            return {"memmap": ref, "index": self.index}
        return {"base": self.base, "index": self.index}

    def __setstate__(self, state: dict[str, Any]) -> None:
        base = open_memmap_ref(state["memmap"]) if "memmap" in state else state["base"]
        self.__init__(base, state["index"])  # type: ignore[misc]

    def __repr__(self) -> str:
        return f"RowSubset({self.shape[0]} of {self.base.shape[0]} rows, dtype={self.dtype})"
