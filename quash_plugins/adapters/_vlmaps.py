"""``vlmaps``: the current VLMaps 3D package's HDF5 map (``vlmap/vlmaps.h5df``).

VLMaps writes one HDF5 file per scene (``vlmap/vlmaps.h5df`` for mobile-base maps,
``vlmap_cam/vlmaps_cam.h5df`` for camera-base maps; forks use names such as
``vlmaps-lseg-0.05.h5df``). Datasets:

================== ================ ===================================================
``grid_feat``      (N, D) float     LSeg/CLIP features, arbitrary norms (required)
``grid_pos``       (N, 3) int32     ``[row, col, height]`` cells (required; camera-base:
                                    ``[row, height, col]``, y up)
``grid_rgb``       (N, 3) uint8     colour (float 0-255 in some builds)
``weight``         (N,) float32     accumulated fusion weight
``occupied_ids``   (gs, gs, vh)     -1 where empty, else the row index (camera-base:
                   (nx, ny, nz))
``mapped_iter_list`` (F,) int32     frames already fused
``pcd_min/pcd_max`` (3,) float64    camera-base maps only
``cs``             scalar float64   camera-base maps only: cell size in metres
``grid_semantic``  (N,) int         forks: ground-truth class per row
================== ================ ===================================================

Only ``grid_feat`` and ``grid_pos`` are required. The grid size ``gs`` of a mobile-base
map is ``occupied_ids.shape[0]``; a camera-base map stores ``cs``. Both are read from the
file, and a configured ``gs`` or ``cs`` that disagrees with it is an error naming both
(a map built with gs = 400 and read with 1000 would be off by 15 m). Mobile-base files
do not store ``cs``: it comes from the ``cs`` option (VLMaps' default 0.05).

Positions are cell centres by default (see :mod:`._vlmaps_common`); pass
``positions="upstream"`` for VLMaps' own ``grid_id2base_pos_3d``. An empty map (no point
was fused: ``grid_feat`` of shape (0, D)) is read as a map of 0 items. ``grid_feat`` stays
on disk (never copied; float16 stays float16) and is L2-normalised chunk by chunk when
read (``LatentMap.normalize``). Zero rows are unobserved and never match.

The file is read read-only and closed: ``grid_feat`` is an
:class:`~quash_plugins.core.h5rows.H5Rows` view that opens the file for each block it
reads, without HDF5's file lock where it can. No lock is held while the map lives, so a
mapping process can save the map again (VLMaps' ``save_3d_map``), and the caller can
open the file with ``h5py`` too. A view whose file changed since the map was read
refuses to read it; a :class:`~quash_plugins.Quash` reads a changed map anew.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.h5rows import H5Rows, open_h5_read
from ..core.interfaces import MapAdapter
from ..core.types import LatentMap, record_inputs
from ._npz import encoder_record
from ._rows import scan_finite
from ._vlmaps_common import (
    FINITE_FIX,
    POSE_TYPES,
    UP_AXIS,
    camera_base_positions,
    check_labels,
    find_obj2cls,
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

REQUIRED = ("grid_feat", "grid_pos")
#: Where VLMaps forks keep per-cell label ids; a map without it has no ground truth.
SEMANTIC_FIELD = "grid_semantic"
#: File names VLMaps writes, looked up when the source is a directory.
KNOWN_NAMES = ("vlmap/vlmaps.h5df", "vlmap_cam/vlmaps_cam.h5df", "vlmaps.h5df", "vlmaps_cam.h5df")
#: What to give a ``cs`` option on a camera-base file that stores no ``cs``: it cannot be
#: dropped there (the cells are placed by ``pcd_min + grid_pos * cs``).
CAMERA_CS_FIX = (
    "Give the map config's cell_size, in metres (VLMaps' default: 0.05): this camera-base "
    "map stores no cs of its own."
)


def import_h5py() -> Any:
    try:
        import h5py
    except ImportError:  # pragma: no cover - h5py is a dev dependency
        raise QuashError(
            'Reading VLMaps HDF5 maps needs h5py: pip install "quash-plugins[hdf5]"'
        ) from None
    return h5py


def resolve_h5(source: Any) -> Path | None:
    """The HDF5 file for ``source``: the file itself, or VLMaps' file inside a folder."""
    if not isinstance(source, (str, Path)):
        return None
    p = Path(source).expanduser()
    if p.is_file():
        return p
    if p.is_dir():
        for name in KNOWN_NAMES:
            if (p / name).is_file():
                return p / name
        hits = sorted(q for q in p.iterdir() if q.suffix in (".h5df",) and q.is_file())
        if len(hits) == 1:
            return hits[0]
    return None


def _note_top_down_map(source: Any, path: Path) -> None:
    """A scene folder that holds the 2023 release's top-down map (``map/grid_lseg_1.npy``)
    beside the 3D one read: say which was read and how to read the other, as a scene
    VLMaps' two releases both ran on has both and auto picks the 3D map silently."""
    if not isinstance(source, (str, Path)) or not Path(source).expanduser().is_dir():
        return
    from ._vlmaps2d import resolve_grid

    grid = resolve_grid(source)
    if grid is not None:
        log.info(
            "%s: read the 3D map %s; the folder also holds the 2023 top-down map %s, "
            "which --adapter vlmaps-2d reads (adapter='vlmaps-2d' in Python).",
            source,
            path,
            grid,
        )


class VLMapsAdapter(MapAdapter):
    """Read a VLMaps 3D HDF5 map (``vlmaps.h5df``, ``vlmaps_cam.h5df``, any ``*.h5df``/``*.h5``
    holding ``grid_feat`` and ``grid_pos``).

    Parameters
    ----------
    gs
        Grid size in cells of mobile-base maps (VLMaps ``map_config.grid_size``). Read
        from ``occupied_ids`` when the file has it; a value here must then agree. Used
        (default 1000) only for files without ``occupied_ids``. A camera-base map has no
        grid size: a value here is refused.
    cs
        Cell size in metres (``map_config.cell_size``, default 0.05) of mobile-base maps,
        whose files do not store it. Camera-base files store ``cs``; a value here must
        then agree.
    positions
        ``"centre"`` (default): each cell's centre in metres. ``"upstream"``: VLMaps' own
        ``grid_id2base_pos_3d`` (the cell face nearest the origin). Camera-base maps:
        both are ``pcd_min + grid_pos * cs``, the exact cell centre.
    pose_type
        ``"auto"`` (camera-base when the file holds ``pcd_min``), ``"mobile_base"`` or
        ``"camera_base"``.
    label_names
        Names of the ``grid_semantic`` class ids: a ``.txt`` (one per line, or VLMaps'
        ``obj2cls_dict.txt``), ``.yaml``/``.json`` list or ``{id: name}``, or the
        list/mapping itself. Default: an ``obj2cls_dict.txt`` next to the map, if any.
    semantic_field
        Dataset holding ground truth (``grid_semantic``); missing is fine. Another name
        that the file lacks is an error naming the file's datasets.
    check_finite
        Scan ``grid_feat`` once at read time for NaN/Inf and unreadable (truncated)
        chunks. Set False for very large maps: the query pass still rejects NaN/Inf.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> a = VLMapsAdapter()
    >>> path = a.write_example(pathlib.Path(tempfile.mkdtemp()))
    >>> m = a.read(path)
    >>> m.kind, m.n, m.normalize
    ('voxels', 60, True)
    """

    name = "vlmaps"
    priority = 20
    suffixes = (".h5df",)
    magic = (b"\x89HDF\r\n\x1a\n",)
    #: Scene sub-folders VLMaps writes its map into (claimed even when the file is missing).
    folders = ("vlmap", "vlmap_cam")

    def __init__(
        self,
        gs: int | None = None,
        cs: float | None = None,
        pose_type: str = "auto",
        label_names: Any = None,
        semantic_field: str = SEMANTIC_FIELD,
        check_finite: bool = True,
        positions: str = "centre",
    ) -> None:
        self.gs = gs
        self.cs = cs
        self.positions = positions
        self.pose_type = pose_type
        self.label_names = label_names
        self.semantic_field = semantic_field
        self.check_finite = check_finite

    # ------------------------------------------------------------------ sniff
    def sniff(self, source: Any) -> bool:
        try:
            path = resolve_h5(source)
            if path is None:
                return False
            import h5py

            if not h5py.is_hdf5(path):
                return False
            with open_h5_read(path) as f:
                return all(k in f for k in REQUIRED)
        except Exception:  # noqa: BLE001 - sniff never raises
            return False

    # ------------------------------------------------------------------ read
    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self._options(options)
        path = resolve_h5(source)
        if path is None:
            _explain_missing_file(source)
            raise MapFormatError(
                f"{source}: not a VLMaps map file. Pass vlmap/vlmaps.h5df (or any .h5df/.h5 "
                "holding 'grid_feat' and 'grid_pos') or the folder that holds it."
                f"{_scenes_inside(source)}"
            )
        _note_top_down_map(source, path)
        import_h5py()
        try:
            f = open_h5_read(path)
        except OSError as exc:
            raise MapFormatError(
                f"{path}: not a readable HDF5 file ({exc}). It may be truncated or not HDF5."
            ) from None
        # the file is closed once read: grid_feat stays on disk, an H5Rows view that
        # opens the file for each read (no lock held while the map lives)
        with f:
            try:
                return self._read_open(f, path, opts)
            except MapFormatError:
                raise
            except (OSError, KeyError, ValueError, TypeError) as exc:
                raise MapFormatError(f"{path}: cannot read the VLMaps map ({exc}).") from None

    def _options(self, options: dict[str, Any]) -> dict[str, Any]:
        opts = self.options(options)
        if opts["pose_type"] not in POSE_TYPES:
            raise QuashError(
                f"Adapter 'vlmaps': pose_type must be one of {POSE_TYPES}; "
                f"got {opts['pose_type']!r}."
            )
        opts["positions"] = check_positions_option(opts["positions"], self.name)
        return opts

    def _read_open(self, f: Any, path: Path, opts: dict[str, Any]) -> LatentMap:
        where = str(path)
        missing = [k for k in REQUIRED if k not in f]
        if missing:
            raise MapFormatError(
                f"{where}: missing dataset(s) {', '.join(map(repr, missing))}. A VLMaps map "
                f"needs 'grid_feat' (N, D) and 'grid_pos' (N, 3). Found: {', '.join(f.keys())}."
            )
        feat = f["grid_feat"]
        if not hasattr(feat, "shape") or len(feat.shape) != 2:
            raise MapFormatError(
                f"{where}: field 'grid_feat' must be 2-D (N, D); got shape "
                f"{getattr(feat, 'shape', None)}."
            )
        n, d = (int(x) for x in feat.shape)
        if d == 0:
            raise MapFormatError(
                f"{where}: field 'grid_feat' has no feature dimension (shape {feat.shape})."
            )
        if feat.dtype.kind not in "fiu":
            raise MapFormatError(f"{where}: field 'grid_feat' must hold numbers; got {feat.dtype}.")
        grid_pos = np.asarray(f["grid_pos"][()])
        if n == 0 and grid_pos.size == 0:
            grid_pos = grid_pos.reshape(0, 3)
        if grid_pos.shape != (n, 3):
            raise MapFormatError(
                f"{where}: field 'grid_pos' must have shape (N, 3) with N = {n} (rows of "
                f"'grid_feat'); got {grid_pos.shape}."
            )
        if grid_pos.dtype.kind not in "fiu" or (
            grid_pos.dtype.kind == "f" and not np.isfinite(grid_pos).all()
        ):
            raise MapFormatError(f"{where}: field 'grid_pos' must hold finite cell indices.")
        if opts["check_finite"] and n:
            rows = max(1, (64 * 2**20) // (4 * d))
            scan_finite(feat, where, "grid_feat", rows, fix=FINITE_FIX, name_read_errors=True)

        pose_type = opts["pose_type"]
        if pose_type == "auto":
            pose_type = "camera_base" if "pcd_min" in f else "mobile_base"
        source: dict[str, Any] = {
            "adapter": self.name,
            "path": where,
            "format": "vlmaps-h5df",
            "pose_type": pose_type,
            "up": UP_AXIS[pose_type],
            "encoder_hint": f"lseg CLIP ViT-B/32 {d}" if d == 512 else f"{d}-d features",
        }
        occupied = f["occupied_ids"].shape if "occupied_ids" in f else None
        if pose_type == "camera_base":
            if "pcd_min" not in f:
                raise MapFormatError(
                    f"{where}: pose_type 'camera_base' needs field 'pcd_min' (3,), which is "
                    "missing. Use pose_type='mobile_base' for mobile-base maps."
                )
            pcd_min = np.asarray(f["pcd_min"][()], dtype=np.float64).reshape(-1)
            if pcd_min.shape != (3,) or not np.isfinite(pcd_min).all():
                raise MapFormatError(f"{where}: field 'pcd_min' must be 3 finite numbers.")
            refuse_camera_base_gs(opts["gs"], where)
            cs = opts["cs"]
            if "cs" in f:
                stored = np.asarray(f["cs"][()], dtype=np.float64).reshape(-1)
                if stored.size != 1:
                    raise MapFormatError(
                        f"{where}: field 'cs' must be one number (the cell size); got shape "
                        f"{stored.shape}."
                    )
                check_against_stored(
                    cs,
                    float(stored[0]),
                    "cs",
                    where,
                    "field 'cs'",
                    "Drop the cs option: camera-base maps store their cell size.",
                )
                cs = float(stored[0])
                _check_stored_cs(cs, where)
            elif cs is None:
                raise MapFormatError(
                    f"{where}: camera-base map lacks field 'cs'; pass the map config's "
                    "cell_size as option cs."
                )
            else:  # no cs of its own: the option gives it, checked like any other
                cs = option_number(cs, "cs", where, CAMERA_CS_FIX)
            positions = camera_base_positions(grid_pos, pcd_min, float(cs))
            source["pcd_min"] = pcd_min.tolist()
            if occupied is not None:
                source["grid_shape"] = [int(x) for x in occupied]
        else:
            gs, gs_from = mobile_grid_size(occupied, opts["gs"], where, "occupied_ids")
            check_cells_in_grid(grid_pos, gs, where, "grid_pos")
            cs = opts["cs"]
            cs = DEFAULT_CS if cs is None else option_number(cs, "cs", where, CS_FIX)
            source["cs_from"] = "default" if opts["cs"] is None else "option"
            if opts["cs"] is None:  # mobile-base files never store it: positions scale by it
                log.info(
                    "%s: mobile-base maps store no cell size; positions use VLMaps' default "
                    "cs = %g m (pass the map config's cell_size as option cs if it differs)",
                    where,
                    DEFAULT_CS,
                )
            positions = mobile_base_positions(grid_pos, gs, float(cs), opts["positions"])
            source["gs"] = int(gs)
            source["gs_from"] = gs_from
            source["positions"] = opts["positions"]
        cs = float(cs)
        source["cs"] = cs

        colors = None
        if "grid_rgb" in f:
            rgb = np.asarray(f["grid_rgb"][()])
            if rgb.shape != (n, 3):
                raise MapFormatError(
                    f"{where}: field 'grid_rgb' must have shape (N, 3) with N = {n}; got "
                    f"{rgb.shape}."
                )
            colors = rgb_to_uint8(rgb, where)

        labels = None
        sem = opts["semantic_field"]
        if sem and sem not in f and sem != SEMANTIC_FIELD:  # named, not the default
            raise MapFormatError(
                f"{where}: semantic_field {sem!r} names no dataset of the file. Found: "
                f"{', '.join(f.keys())}. Give the dataset of per-cell label ids (VLMaps "
                f"forks write {SEMANTIC_FIELD!r}), or leave the option out."
            )
        if sem and sem in f:
            labels = check_labels(f[sem][()], n, where, sem)
        names_spec = opts["label_names"]
        if names_spec is None and labels is not None:
            names_spec = find_obj2cls(path, levels=2)
        names = load_label_names(names_spec)
        names = fit_label_names(names, labels, names_spec, f"{where} ({sem})")
        if "mapped_iter_list" in f:
            source["frames_fused"] = int(np.asarray(f["mapped_iter_list"]).size)
        source.update(encoder_record(dict(f.attrs)))
        record_inputs(source, names_spec)  # a file of names (obj2cls_dict.txt) read with it
        return LatentMap(
            embeddings=H5Rows.from_dataset(feat),
            kind="voxels",
            positions=positions,
            colors=colors,
            labels=labels,
            label_names=names,
            voxel_size=cs,
            grid_index=grid_pos.astype(np.int64),
            normalize=True,
            source=source,
        )

    # ------------------------------------------------------------------ example
    def write_example(self, directory: Path) -> Path:
        """A small mobile-base ``vlmap/vlmaps.h5df`` written the way VLMaps writes it."""
        h5py = import_h5py()
        rng = np.random.default_rng(0)
        path = Path(directory) / "vlmap" / "vlmaps.h5df"
        path.parent.mkdir(parents=True, exist_ok=True)
        n, d, gs, vh = 60, 8, 40, 10
        cells = rng.choice(gs * gs * vh, size=n, replace=False)
        grid_pos = np.stack(np.unravel_index(cells, (gs, gs, vh)), axis=1).astype(np.int32)
        occupied = -np.ones((gs, gs, vh), dtype=np.int32)
        occupied[grid_pos[:, 0], grid_pos[:, 1], grid_pos[:, 2]] = np.arange(n, dtype=np.int32)
        feat = rng.normal(size=(n, d)).astype(np.float32) * rng.uniform(0.1, 3, size=(n, 1))
        with h5py.File(path, "w") as f:
            f.create_dataset("mapped_iter_list", data=np.arange(5, dtype=np.int32))
            f.create_dataset("grid_feat", data=feat.astype(np.float32))
            f.create_dataset("grid_pos", data=grid_pos)
            f.create_dataset("weight", data=rng.uniform(0.1, 2, size=n).astype(np.float32))
            f.create_dataset("occupied_ids", data=occupied)
            f.create_dataset("grid_rgb", data=rng.integers(0, 256, (n, 3), dtype=np.uint8))
        return path


def _explain_missing_file(source: Any) -> None:
    """Raise naming the VLMaps sub-folder of ``source`` that lacks its map file, if any."""
    if not isinstance(source, (str, Path)) or not Path(source).expanduser().is_dir():
        return
    folder = Path(source).expanduser()
    for name in KNOWN_NAMES[:2]:
        sub, file = name.split("/")
        if (folder / sub).is_dir() and not (folder / name).exists():
            # a fork's file under its own name (vlmaps-lseg-0.05.h5df): name it and the fix
            held = sorted(p for p in (folder / sub).glob("*.h5*") if p.is_file())
            if held:
                raise MapFormatError(
                    f"{folder / sub}/ has no {file}, but holds "
                    f"{', '.join(p.name for p in held)}: pass the map file itself "
                    f"({held[0]})."
                )
            raise MapFormatError(
                f"{folder / sub}/ has no {file}. VLMaps writes it there when the map is "
                f"built (VLMap.create_map); build or copy the map, or pass the .h5df file "
                "itself."
            )


def _scenes_inside(source: Any, limit: int = 256, shown: int = 5) -> str:
    """For a folder of scene folders (VLMaps' data root, ``data/<scene>/vlmap/``): a
    sentence naming the scenes whose map file is found, to pass one; else ``""``."""
    folder = Path(source).expanduser() if isinstance(source, (str, Path)) else None
    if folder is None or not folder.is_dir():
        return ""
    try:
        subs = sorted(p for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))
    except OSError:
        return ""
    scenes = [sub for sub in subs[:limit] if resolve_h5(sub) is not None]
    if not scenes:
        return ""
    more = f" and {len(scenes) - shown} more" if len(scenes) > shown else ""
    listed = ", ".join(str(sub) for sub in scenes[:shown])
    return f" It holds scene folders with a VLMaps map: {listed}{more}; pass one of them."


def _check_stored_cs(cs: float, where: str) -> None:
    """A camera-base file's own ``cs`` (options are checked by ``option_number``)."""
    if not (0 < cs < np.inf):
        raise MapFormatError(
            f"{where}: field 'cs' (the cell size) must be a positive number; got {cs:g}."
        )
