"""``vlmaps-live``: a VLMaps ``VLMap`` object already in memory, recognised by duck typing.

Any object with ``grid_feat`` (N, D) and ``grid_pos`` (N, 3) attributes is accepted.
Optional attributes: ``grid_rgb`` (N, 3), ``occupied_ids``, ``gs``, ``cs``, ``pcd_min``
(camera-base maps) and ``map_config.pose_info.pose_type`` (``"mobile_base"`` or
``"camera_base"``; an OmegaConf config or a plain dict). VLMaps itself is never imported.

The grid size of a mobile-base map is ``occupied_ids.shape[0]`` when the object has
``occupied_ids`` (``VLMap.load_map`` loads it from the file): an explicit ``gs`` option
that disagrees is an error naming both, and a ``vlmap.gs`` (VLMaps' config value) that
disagrees is reported as a warning, since VLMaps' own ``get_pos`` would then use the
wrong grid. Positions are cell centres by default (``positions="upstream"`` for VLMaps'
``grid_id2base_pos_3d``), as for the ``vlmaps`` file adapter.

``grid_feat`` is used as it is (no copy; a torch tensor is viewed through ``.numpy()``)
and never written: rows are L2-normalised as they are read (the pipeline scales its
products instead of the rows), and zero rows never match. Positions follow the same
formulas as the ``vlmaps`` file adapter.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.interfaces import MapAdapter
from ..core.types import LatentMap, record_inputs
from ._rows import scan_finite
from ._vlmaps_common import (
    POSE_TYPES,
    UP_AXIS,
    camera_base_positions,
    check_labels,
    fit_label_names,
    load_label_names,
    mobile_base_positions,
    rgb_to_uint8,
)
from ._vlmaps_options import (
    CS_FIX,
    DEFAULT_CS,
    check_against_stored,
    check_cells_in_grid,
    check_positions_option,
    mobile_grid_size,
    option_number,
    refuse_camera_base_gs,
)

log = logging.getLogger(__name__)

#: The fix for NaN/Inf rows of a live map (the live adapter has no check_finite option).
LIVE_FINITE_FIX = (
    "Set those rows to zero, e.g. vlmap.grid_feat[~np.isfinite(vlmap.grid_feat).all(axis=1)] "
    "= 0: a zero row is an unobserved cell and never matches."
)


def _lookup(obj: Any, *names: str) -> Any:
    """``obj.a.b.c`` that also walks dicts; None when any step is missing."""
    for name in names:
        if obj is None:
            return None
        if isinstance(obj, dict):
            obj = obj.get(name)
        else:
            try:
                obj = getattr(obj, name, None)
            except Exception:  # noqa: BLE001 - OmegaConf may raise on missing keys
                return None
    return obj


def as_array(value: Any) -> Any:
    """A numpy-compatible view of ``value`` (torch tensors are moved to CPU numpy)."""
    if type(value).__module__.startswith("torch"):
        return value.detach().cpu().numpy()
    if hasattr(value, "shape") and hasattr(value, "dtype") and hasattr(value, "__getitem__"):
        return value
    return np.asarray(value)


def pose_type_of(vlmap: Any) -> str | None:
    value = _lookup(vlmap, "map_config", "pose_info", "pose_type")
    return str(value) if value is not None else None


def _loaded_from(vlmap: Any, option: Any, where: str) -> str | None:
    """The file a live map was loaded from: the ``path`` option, or with ``"auto"``
    ``vlmap.map_save_path`` (``VLMap.load_map`` sets it) when that file exists."""
    if option is None:
        return None
    if isinstance(option, str) and option == "auto":
        saved = getattr(vlmap, "map_save_path", None)
        if isinstance(saved, (str, Path)) and str(saved) and Path(saved).is_file():
            return str(saved)
        return None
    if not isinstance(option, (str, Path)) or not Path(option).is_file():
        raise MapFormatError(
            f"{where}: path={option!r} is not a file. Give the file the map was loaded "
            "from (VLMaps: DATA_DIR/vlmap_cam/vlmaps_cam.h5df or DATA_DIR/vlmap/vlmaps.h5df), "
            "'auto' (vlmap.map_save_path) or None."
        )
    return str(option)


class VLMapsLiveAdapter(MapAdapter):
    """Read a live VLMaps ``VLMap`` (or any object with ``grid_feat`` and ``grid_pos``).

    Parameters
    ----------
    gs
        Grid size of mobile-base maps; must agree with ``occupied_ids`` when the object
        has it. Otherwise it overrides the object's ``gs`` (default 1000). Refused on a
        camera-base map, which has no grid size.
    cs
        Cell size in metres; overrides the object's ``cs`` (default 0.05). For
        camera-base maps (whose ``cs`` ``VLMap.load_map`` reads from the file) it must agree.
    positions
        ``"centre"`` (default) or ``"upstream"``, as for the ``vlmaps`` adapter.
    pose_type
        ``"auto"`` (the object's ``map_config.pose_info.pose_type``; camera-base when it
        has ``pcd_min``), ``"mobile_base"`` or ``"camera_base"``.
    label_names
        Names for an optional ``grid_semantic`` attribute (see the ``vlmaps`` adapter).
    path
        The file the live map was loaded from, recorded as ``source["path"]`` so that
        the taxonomy beside it (``MAP.taxonomy.yaml``, which ``quash convert --format
        vlmaps`` writes) is found as it is for the file. ``"auto"`` (the default) takes
        ``vlmap.map_save_path`` (set by ``VLMap.load_map``) when that file exists; a
        path names it (it must exist); None records no file.

    Examples
    --------
    >>> import numpy as np
    >>> from types import SimpleNamespace
    >>> vlmap = SimpleNamespace(grid_feat=np.eye(3, dtype=np.float32),
    ...                         grid_pos=np.array([[500, 500, 0], [499, 500, 2], [500, 498, 1]]))
    >>> m = VLMapsLiveAdapter().read(vlmap)
    >>> [round(float(x), 3) for x in m.positions[1]]
    [0.075, 0.0, 0.125]
    >>> up = VLMapsLiveAdapter(positions="upstream").read(vlmap)
    >>> [round(float(x), 3) for x in up.positions[1]]
    [0.05, 0.0, 0.1]
    """

    name = "vlmaps-live"
    priority = 30

    def __init__(
        self,
        gs: int | None = None,
        cs: float | None = None,
        pose_type: str = "auto",
        label_names: Any = None,
        positions: str = "centre",
        path: str | Path | None = "auto",
    ) -> None:
        self.gs = gs
        self.cs = cs
        self.pose_type = pose_type
        self.label_names = label_names
        self.positions = positions
        self.path = path

    def sniff(self, source: Any) -> bool:
        try:
            if isinstance(source, (str, Path, LatentMap, dict)):
                return False
            feat = getattr(source, "grid_feat", None)
            pos = getattr(source, "grid_pos", None)
            return (
                feat is not None
                and pos is not None
                and len(getattr(feat, "shape", ())) == 2
                and len(getattr(pos, "shape", ())) == 2
            )
        except Exception:  # noqa: BLE001 - sniff never raises
            return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        opts["positions"] = check_positions_option(opts["positions"], self.name)
        if isinstance(source, (str, Path)):  # a file: it has no arrays to load first
            raise MapFormatError(
                f"{source}: the 'vlmaps-live' adapter reads a VLMap object in Python "
                "(index_map(vlmap, ...), Quash.query(vlmap, ...)), not a file or folder."
            )
        where = f"live {type(source).__name__} object"
        for field in ("grid_feat", "grid_pos"):
            if getattr(source, field, None) is None:
                raise MapFormatError(
                    f"{where}: attribute {field!r} is missing or None. Load or build the map "
                    "first (VLMap.load_map / create_map)."
                )
        feat = as_array(source.grid_feat)
        if len(feat.shape) != 2 or feat.shape[1] == 0:
            raise MapFormatError(
                f"{where}: 'grid_feat' must be (N, D) with D > 0; got {feat.shape}."
            )
        n = int(feat.shape[0])
        scan_finite(feat, where, "grid_feat", fix=LIVE_FINITE_FIX, name_read_errors=True)
        grid_pos = np.asarray(as_array(source.grid_pos))
        if n == 0 and grid_pos.size == 0:
            grid_pos = grid_pos.reshape(0, 3)
        if grid_pos.shape != (n, 3) or grid_pos.dtype.kind not in "fiu":
            raise MapFormatError(
                f"{where}: 'grid_pos' must be numeric with shape (N, 3), N = {n}; got "
                f"{grid_pos.shape} {grid_pos.dtype}."
            )
        pose_type = opts["pose_type"]
        if pose_type not in POSE_TYPES:
            raise QuashError(f"pose_type must be one of {POSE_TYPES}; got {pose_type!r}.")
        if pose_type == "auto":
            pose_type = pose_type_of(source) or (
                "camera_base" if getattr(source, "pcd_min", None) is not None else "mobile_base"
            )
        own_cs = None
        if getattr(source, "cs", None) is not None:
            try:
                own_cs = _own_cs(source.cs, where)
            except MapFormatError:
                if opts["cs"] is None:
                    raise
                # the fix it names: a cs option replaces an own cs that is no size
        if pose_type == "camera_base" and own_cs is not None:
            check_against_stored(
                opts["cs"],
                own_cs,
                "cs",
                where,
                "attribute 'cs' (read from the camera-base file by VLMap.load_map)",
                "Drop the cs option.",
            )
        if opts["cs"] is not None:
            cs = option_number(opts["cs"], "cs", where, CS_FIX)
        else:
            cs = DEFAULT_CS if own_cs is None else own_cs
        source_meta: dict[str, Any] = {
            "adapter": self.name,
            "live": type(source).__name__,
            "pose_type": pose_type,
            "cs": cs,
        }
        if pose_type == "camera_base":
            pcd_min = getattr(source, "pcd_min", None)
            if pcd_min is None:
                raise MapFormatError(
                    f"{where}: a camera_base map needs attribute 'pcd_min' (3,); it is missing."
                )
            refuse_camera_base_gs(opts["gs"], where)
            positions = camera_base_positions(grid_pos, np.asarray(pcd_min).reshape(3), cs)
        elif pose_type == "mobile_base":
            occupied = getattr(getattr(source, "occupied_ids", None), "shape", None)
            own_gs = getattr(source, "gs", None)
            if occupied is None and opts["gs"] is None and own_gs is not None:
                gs, gs_from = _own_gs(own_gs, where), "attribute"
            else:
                gs, gs_from = mobile_grid_size(occupied, opts["gs"], where, "occupied_ids")
            if occupied is not None and own_gs is not None and not _equals(own_gs, gs):
                log.warning(
                    "%s: vlmap.gs = %s (the map config's grid_size) disagrees with "
                    "occupied_ids, which gives gs = %d; using %d. Fix grid_size in your "
                    "VLMaps map config: VLMaps' own get_pos uses it.",
                    where,
                    own_gs,
                    gs,
                    gs,
                )
            check_cells_in_grid(grid_pos, gs, where, "grid_pos")
            positions = mobile_base_positions(grid_pos, gs, cs, opts["positions"])
            source_meta["gs"] = int(gs)
            source_meta["gs_from"] = gs_from
            source_meta["positions"] = opts["positions"]
        else:
            raise MapFormatError(f"{where}: unknown map_config.pose_info.pose_type {pose_type!r}.")
        source_meta["up"] = UP_AXIS[pose_type]
        loaded_from = _loaded_from(source, opts["path"], where)
        if loaded_from is not None:
            source_meta["path"] = loaded_from
        colors = None
        rgb = getattr(source, "grid_rgb", None)
        if rgb is not None:
            rgb = np.asarray(as_array(rgb))
            if rgb.shape != (n, 3):
                raise MapFormatError(
                    f"{where}: 'grid_rgb' must be (N, 3), N = {n}; got {rgb.shape}."
                )
            colors = rgb_to_uint8(rgb, where)
        labels = None
        sem = getattr(source, "grid_semantic", None)
        if sem is not None:
            labels = check_labels(as_array(sem), n, where, "grid_semantic")
        names = fit_label_names(
            load_label_names(opts["label_names"]),
            labels,
            opts["label_names"],
            f"{where} (grid_semantic)",
        )
        return LatentMap(
            embeddings=feat,  # read as it is: the pipeline never writes into it
            kind="voxels",
            positions=positions,
            colors=colors,
            labels=labels,
            label_names=names,
            voxel_size=cs,
            grid_index=grid_pos.astype(np.int64),
            normalize=True,
            source=record_inputs(source_meta, opts["label_names"]),  # a names file, if any
        )

    def write_example(self, directory: Path) -> Any:
        """A small duck-typed VLMap-like object (live adapters return the object)."""
        from types import SimpleNamespace

        rng = np.random.default_rng(0)
        n, d = 50, 8
        return SimpleNamespace(
            grid_feat=rng.normal(size=(n, d)).astype(np.float32),
            grid_pos=np.column_stack(
                [rng.integers(480, 520, n), rng.integers(480, 520, n), rng.integers(0, 30, n)]
            ).astype(np.int32),
            grid_rgb=rng.integers(0, 256, (n, 3), dtype=np.uint8),
            gs=1000,
            cs=0.05,
            map_config={"pose_info": {"pose_type": "mobile_base"}},
        )


def _own_gs(own_gs: Any, where: str) -> int:
    """A live map's own ``vlmap.gs`` (its map config's grid_size), a positive whole
    number, else :class:`MapFormatError` naming the attribute, not an option."""
    return option_number(
        own_gs,
        "gs",
        where,
        "Set grid_size in its map config, in cells per side (VLMaps' default: 1000), or "
        "pass the gs option.",
        whole=True,
        what=f"the VLMap object's gs attribute (vlmap.gs={own_gs!r}, its map config's grid_size)",
    )


def _own_cs(own_cs: Any, where: str) -> float:
    """A live map's own ``vlmap.cs`` (its map config's cell_size; a one-element array is
    read as its value), a positive number, else :class:`MapFormatError` naming the
    attribute, not an option."""
    value = own_cs
    with contextlib.suppress(Exception):
        arr = np.asarray(own_cs)
        if arr.size == 1 and arr.dtype.kind in "biuf":
            value = arr.reshape(-1)[0].item()
    return float(
        option_number(
            value,
            "cs",
            where,
            "Set cell_size in its map config, in metres (VLMaps' default: 0.05), or pass "
            "the cs option.",
            what=f"the VLMap object's cs attribute (vlmap.cs={value!r}, its map config's "
            "cell_size)",
        )
    )


def _equals(value: Any, number: int) -> bool:
    """Whether ``value`` is ``number`` (False for a value that is no number)."""
    try:
        return float(value) == number
    except (TypeError, ValueError):
        return False
