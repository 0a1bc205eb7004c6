"""A map's layout as files record it: the up axis of its positions and a pixel map's frames.

One definition for every file that carries them: the portable NPZ map
(``adapters/_npz.py``, ``quash convert``), the results of ``quash query --out``
(``engine/results.py``: a results NPZ's arrays, a results Zarr store's attributes) and
their readers (the ``npz`` adapter, ``frames_from_npz`` and ``frames_from_zarr``,
``up_from_npz`` and ``up_from_zarr``). The fields:

- ``up``: a string, one of :data:`~quash_plugins.core.types.UP_AXES` (``"+y"`` for a
  VLMaps camera-base map); absent when nothing says, and ``+z`` is then assumed;
- ``frame_ids (F,)`` str, ``frame_hw (F, 2)`` int and ``frame_offsets (F,)`` int: where
  each image's pixels sit in a pixel map's item axis (:class:`FrameInfo`, without the
  image paths).

:func:`map_layout` gives them as plain values (a Zarr store's JSON attributes),
:func:`layout_arrays` as the arrays an NPZ stores, and :func:`read_up` and
:func:`read_frames` read either back, refusing a malformed field by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from .errors import MapFormatError
from .types import UP_AXES, FrameInfo

#: The fields of a pixel map's frames, in the order they are written.
FRAME_KEYS = ("frame_ids", "frame_hw", "frame_offsets")
#: Every layout field.
LAYOUT_KEYS = (*FRAME_KEYS, "up")


def layout_up(source: Mapping[str, Any] | None, up: str | None = None) -> str | None:
    """The up axis to record: ``up`` when given (``--up``), else the one ``source`` (a
    map's ``LatentMap.source``) records; None unless it is one of ``UP_AXES``.

    >>> layout_up({"up": "+y"}), layout_up({"up": "+y"}, "-z"), layout_up({})
    ('+y', '-z', None)
    """
    axis = up if up is not None else (source or {}).get("up")
    return axis if axis in UP_AXES else None


def frame_layout(lmap: Any) -> dict[str, list]:
    """``lmap``'s frames as plain lists (``frame_ids``, ``frame_hw``, ``frame_offsets``);
    ``{}`` for a map without frames (or frames that do not cover its items)."""
    frames = getattr(lmap, "frames", None)
    if not frames or sum(f.size for f in frames) != lmap.n:
        return {}
    return {
        "frame_ids": [str(f.frame_id) for f in frames],
        "frame_hw": [[int(f.height), int(f.width)] for f in frames],
        "frame_offsets": [int(f.offset) for f in frames],
    }


def map_layout(lmap: Any, up: str | None = None) -> dict[str, Any]:
    """``lmap``'s layout as plain values: ``up`` (:func:`layout_up`) when known and the
    frames (:func:`frame_layout`) of a pixel map."""
    out: dict[str, Any] = frame_layout(lmap)
    axis = layout_up(getattr(lmap, "source", None), up)
    if axis is not None:
        out["up"] = axis
    return out


def layout_arrays(layout: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """The NPZ arrays of a :func:`map_layout`: ``up`` a 0-d str, ``frame_ids (F,)`` str,
    ``frame_hw (F, 2)`` and ``frame_offsets (F,)`` int64."""
    out: dict[str, np.ndarray] = {}
    for key in LAYOUT_KEYS:
        if key in layout:
            dtype = str if key in ("up", "frame_ids") else np.int64
            out[key] = np.asarray(layout[key], dtype=dtype)
    if "frame_hw" in out:
        out["frame_hw"] = out["frame_hw"].reshape(-1, 2)
    return out


def read_up(fields: Mapping[str, Any], where: str, what: str = "array") -> str | None:
    """The up axis ``fields`` (an NPZ's arrays, a store's attributes) record, or None.

    A value that is not one of ``UP_AXES`` is refused, naming ``where`` and the field
    (``what`` says how ``where`` stores it: ``array``, ``attribute``).
    """
    if "up" not in fields:
        return None
    up = fields["up"]
    up = str(up) if isinstance(up, (str, np.ndarray)) else up
    if up not in UP_AXES:
        raise MapFormatError(
            f"{where}: {what} 'up' is {up!r}, not an up axis; store one of "
            f"{', '.join(UP_AXES)} (or none: +z is assumed)."
        )
    return up


def read_frames(
    fields: Mapping[str, Any], where: str, what: str = "array"
) -> list[FrameInfo] | None:
    """The frames ``fields`` record (:data:`FRAME_KEYS`), or None without ``frame_ids``.

    ``frame_hw`` must be ``(F, 2)`` and ``frame_offsets`` ``(F,)`` for the ``F``
    ``frame_ids``; else refused, naming ``where`` and the fields.
    """
    if "frame_ids" not in fields:
        return None
    ids = np.asarray(fields["frame_ids"]).reshape(-1)
    hw, off = _int_array(fields.get("frame_hw")), _int_array(fields.get("frame_offsets"))
    if hw is None or off is None or hw.shape != (len(ids), 2) or off.shape != (len(ids),):
        raise MapFormatError(
            f"{where}: {what}s 'frame_hw' must be (F, 2) and 'frame_offsets' (F,) for F = "
            f"{len(ids)} frame_ids; got {_shape(fields.get('frame_hw'))} and "
            f"{_shape(fields.get('frame_offsets'))}. Write the file again."
        )
    return [FrameInfo(str(i), int(h), int(w), int(o)) for i, (h, w), o in zip(ids, hw, off)]


def _int_array(value: Any) -> np.ndarray | None:
    """``value`` as an int64 array, or None when it is missing or not numbers in rows."""
    if value is None:
        return None
    try:
        return np.asarray(value, dtype=np.int64)
    except (TypeError, ValueError):
        return None


def _shape(value: Any) -> Any:
    """The shape of ``value`` for a message: an array's, a list's, else its type."""
    try:
        return np.asarray(value).shape if value is not None else "none"
    except (TypeError, ValueError):
        return type(value).__name__
