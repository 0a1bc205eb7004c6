"""The options of the VLMaps adapters (``gs``, ``cs``, ``positions``), read and checked.

An option is refused where it is read, naming the map, the option and what to give it
(``WHERE: option gs=0 must be a positive whole number. FIX``), rather than later as a
symptom (cells outside ``[0, 0)``); one a map stores itself must agree with the map.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError

log = logging.getLogger(__name__)

#: VLMaps' default map config (``config/map_config/vlmaps.yaml``): grid_size, cell_size.
DEFAULT_GS = 1000
DEFAULT_CS = 0.05
#: How grid cells become metres: the cell's centre, or upstream's own inverse function.
POSITIONS = ("centre", "upstream")


def check_positions_option(value: Any, adapter: str) -> str:
    """``"centre"`` or ``"upstream"`` (``"center"`` is accepted as a spelling)."""
    v = "centre" if value == "center" else value
    if v not in POSITIONS:
        raise QuashError(
            f"Adapter {adapter!r}: positions must be 'centre' (the cell's centre, default) or "
            f"'upstream' (VLMaps' own inverse function, the cell face nearest the origin); "
            f"got {value!r}."
        )
    return str(v)


def check_against_stored(
    option: Any, stored: float, name: str, where: str, field: str, fix: str
) -> None:
    """Raise :class:`MapFormatError` when a configured ``option`` disagrees with the map's,
    or is not a number.

    The message names both values, the field they come from and the fix.
    """
    if option is None:
        return
    if not np.isclose(option_number(option, name, where, fix), float(stored), rtol=1e-9, atol=0.0):
        raise MapFormatError(
            f"{where}: option {name}={option!r} disagrees with the map, whose {field} gives "
            f"{name} = {stored:g}. {fix}"
        )


def option_number(
    option: Any, name: str, where: str, fix: str, *, whole: bool = False, what: str = ""
) -> Any:
    """``option`` as a float (an int when ``whole``), else :class:`MapFormatError`:
    ``WHERE: option NAME=VALUE is not a (whole) number. FIX`` (a bool is no number), or
    ``... must be a positive (whole) number. FIX``: every such option is a size.

    ``what`` names the value when it is no option (a live map's own attribute); it
    replaces ``option NAME=VALUE`` in the message."""
    kind = "whole number" if whole else "number"
    what = what or f"option {name}={option!r}"
    try:
        value = float(option)
        ok = not isinstance(option, bool) and (not whole or value.is_integer())
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise MapFormatError(f"{where}: {what} is not a {kind}. {fix}")
    if not (0 < value < np.inf):  # 0 or less, NaN or infinite
        size = "positive" if np.isfinite(value) else "finite, positive"
        raise MapFormatError(f"{where}: {what} must be a {size} {kind}. {fix}")
    return int(value) if whole else value


#: What to give a ``cs`` option that is not a number.
CS_FIX = (
    "Give the map config's cell_size, in metres (VLMaps' default: 0.05), or drop the cs option."
)


def refuse_camera_base_gs(option: Any, where: str) -> None:
    """Refuse a ``gs`` option on a camera-base map, which has no grid size: its cells
    are placed by ``pcd_min`` and ``cs``, so a ``gs`` would be silently ignored."""
    if option is not None:
        raise MapFormatError(
            f"{where}: option gs={option!r} does not apply to a camera-base map: its cells "
            "are placed by pcd_min and cs, with no grid size. Drop the gs option (it is read "
            "only for mobile-base maps)."
        )


def mobile_grid_size(occupied_shape: Any, option: Any, where: str, field: str) -> tuple[int, str]:
    """``(gs, origin)`` of a mobile-base map: from ``occupied_ids`` when stored, else the
    option, else VLMaps' default 1000. A disagreeing option is an error naming both."""
    if occupied_shape is not None:
        shape = tuple(int(x) for x in occupied_shape)
        if len(shape) != 3 or shape[0] != shape[1] or shape[0] == 0:
            raise MapFormatError(
                f"{where}: field {field!r} of a mobile-base map must have shape (gs, gs, vh); "
                f"got {shape}. If this is a camera-base map, it needs 'pcd_min' and 'cs'."
            )
        check_against_stored(
            option,
            shape[0],
            "gs",
            where,
            f"{field!r} (shape {shape})",
            "Drop the gs option: the grid size is read from the map.",
        )
        return shape[0], field
    if option is not None:
        fix = (
            "Give the map config's grid_size, in cells per side (VLMaps' default: 1000), or "
            "drop the gs option."
        )
        return option_number(option, "gs", where, fix, whole=True), "option"
    log.warning(
        "%s: no %r to read the grid size from; assuming VLMaps' default gs = %d (pass the "
        "map config's grid_size as option gs if it differs)",
        where,
        field,
        DEFAULT_GS,
    )
    return DEFAULT_GS, "default"


def check_cells_in_grid(grid_pos: np.ndarray, gs: int, where: str, field: str) -> None:
    """Rows and columns of a mobile-base map lie in ``[0, gs)``, as the builder keeps them."""
    if len(grid_pos) == 0:
        return
    rc = np.asarray(grid_pos[:, :2])
    if rc.min() < 0 or rc.max() >= gs:
        raise MapFormatError(
            f"{where}: field {field!r} holds rows/columns outside [0, {gs}) (range "
            f"{int(rc.min())}..{int(rc.max())}) for grid size gs = {gs}; the map and its "
            "grid size disagree."
        )
