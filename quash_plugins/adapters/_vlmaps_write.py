"""Write a voxel map in VLMaps' own HDF5 save layout (``quash convert --format vlmaps``).

The layout is the one VLMaps' camera-base builder (``VLMapBuilderCam.save_3d_map``)
writes to ``<scene>/vlmap_cam/vlmaps_cam.h5df`` and ``VLMap.load_map`` reads back when
the map config's ``pose_info.pose_type`` is ``camera_base``:

==================== ============== ================================================
``mapped_iter_list`` (F,) int32     frames fused (empty here: nothing was fused)
``grid_feat``        (N, D) float   the map's embeddings, as stored (not normalised)
``grid_pos``         (N, 3) int32   cells ``[row, height, col]``, ``round((p - pcd_min) / cs)``
``weight``           (N,) float32   fusion weight (1 per row here)
``occupied_ids``     (nr, nh, nc)   -1 where empty, else the row index (height on axis 1)
``grid_rgb``         (N, 3) uint8   colour (grey 128 when the map has none)
``pcd_min/pcd_max``  (3,) float64   the grid's bounds in metres
``cs``               scalar float64 cell size in metres
==================== ============== ================================================

Camera-base rather than mobile-base because it is the layout that stores its own cell
size and origin: positions read back as ``pcd_min + grid_pos * cs`` are the source's
positions, rotated. A mobile-base file stores neither; its positions are fixed by
VLMaps' truncating bins around the grid centre, which a voxel grid from another frame
does not land on.

Cells are counted the way the positions run, not as ``grid_index`` counts them: VLMaps'
mobile-base and 2023 top-down grids count rows and columns against x and y
(``x = (gs/2 - row) * cs``), so those axes are reversed (each cell keeps its neighbours), and
``pcd_min`` is fitted to the positions. Positions that no ``pcd_min + grid_pos * cs``
holds are refused with a :class:`~quash_plugins.core.errors.UsageError` naming the file,
the field and the fix, never written elsewhere: VLMaps' own cell centres across the
origin (``positions: centre``, the default; the truncating bins make the origin cell two
cells wide, so they are not evenly spaced: convert with ``positions=upstream``), and
positions more than half a cell from their ``grid_index`` cell. Positions inside their
cells but off the centres are written as the centres (the voxel rounding), with a
warning.

The camera-base builder (``VLMapBuilderCam.create_camera_map``) bins the camera poses'
world frame, which is y-up: a cell is ``[row, height, col]`` and its top-down image
keeps, per ``(row, col)``, the point of largest height. So the map is turned rigidly
to y-up first (:data:`TO_Y_UP`): a z-up map (the source's ``source["up"]``, or ``+z``
when its format does not say, as for ``quash make-scene``) goes ``(x, y, z) -> (x, z,
-y)``, a proper rotation. Cells are turned with it, so each keeps its neighbours, and
rows keep their order: queries and instances are the same, in the rotated frame. The
``vlmaps`` adapter reads the file back as y-up (``source["up"] == "+y"``).

The encoder that built the map (``encoder``, ``encoder_fingerprint``, ``encoder_params``:
:data:`~quash_plugins.adapters._npz.ENCODER_KEYS`), when the source
records it, is kept as attributes of the file's root group: VLMaps reads datasets by
name and ignores them; the ``vlmaps`` adapter reads them back, so a query with another
encoder warns as it does on the NPZ.

VLMaps has no ground-truth field. Labels are written the way VLMaps forks store them,
as ``grid_semantic`` (N,) int64 with the names in an ``obj2cls_dict.txt`` beside the
file (``id: id, name`` per line); the ``vlmaps`` adapter reads both back, VLMaps
itself ignores them.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..core.errors import UsageError
from ..core.types import LatentMap
from ._npz import ENCODER_KEYS

log = logging.getLogger(__name__)

#: Per source up axis, the proper rotation to VLMaps' camera-base y-up frame, as
#: (source axis, sign) of each output axis: ``+z`` is ``(x, y, z) -> (x, z, -y)``.
TO_Y_UP = {
    "+y": ((0, 1), (1, 1), (2, 1)),
    "-y": ((0, 1), (1, -1), (2, -1)),
    "+z": ((0, 1), (2, 1), (1, -1)),
    "-z": ((0, 1), (2, -1), (1, 1)),
    "+x": ((1, -1), (0, 1), (2, 1)),
    "-x": ((1, 1), (0, -1), (2, 1)),
}

#: Where the file goes inside the destination folder (VLMaps' camera-base path).
H5_NAME = Path("vlmap_cam") / "vlmaps_cam.h5df"
LABELS_NAME = Path("vlmap_cam") / "obj2cls_dict.txt"


def vlmaps_outputs(folder: str | Path, with_labels: bool = True) -> list[Path]:
    """The files :func:`write_vlmaps_map` writes into ``folder``."""
    folder = Path(folder).expanduser()
    return [folder / H5_NAME, *([folder / LABELS_NAME] if with_labels else [])]


def write_vlmaps_map(lmap: LatentMap, folder: str | Path, chunk_rows: int = 65536) -> Path:
    """Write ``lmap`` as ``folder/vlmap_cam/vlmaps_cam.h5df`` in VLMaps' save layout.

    What ``quash convert --format vlmaps`` writes (the layout is in this module's
    docstring). Positions and cells are turned rigidly to VLMaps' y-up frame, cells
    counted the way positions run; rows keep their order. Embeddings are copied
    ``chunk_rows`` rows at a time, float16 stays float16, other dtypes become float32
    (VLMaps' own). Labels, when the map has them,
    go to ``grid_semantic`` and their names to ``folder/vlmap_cam/obj2cls_dict.txt``
    (:func:`vlmaps_outputs` lists the files). Each file is written beside its target and
    renamed into place; an existing file is replaced (the command line checks
    ``--force`` first), and an ``obj2cls_dict.txt`` of a map written there before is
    removed when this map has no label names, so it cannot name this map's labels. Needs ``pip install "quash-plugins[hdf5]"`` (h5py).

    Parameters
    ----------
    lmap : LatentMap
        The map to write, first as for every map writer. It must be a voxel grid
        (``grid_index`` and ``voxel_size``) with ``positions``, one row per cell.
    folder : str or pathlib.Path
        The folder to write into (VLMaps' scene folder); created when missing.
    chunk_rows : int, default 65536
        Rows of embeddings copied at a time.

    Returns
    -------
    pathlib.Path
        The path of the ``.h5df`` file, which the ``vlmaps`` adapter reads back (as
        ``folder``, or this path).

    Raises
    ------
    UsageError
        When the map is not a voxel grid, has no positions, has two rows in one cell,
        records an up axis that is not one of ``+x``, ``-x``, ``+y``, ``-y``, ``+z``,
        ``-z``, or has positions that the file cannot hold (see the module's docstring:
        VLMaps' own cell centres across the origin, or positions more than half a cell
        from their ``grid_index`` cell).
    QuashError
        When h5py is not installed.

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> from quash_plugins import LatentMap
    >>> from quash_plugins.adapters import read_map, write_vlmaps_map
    >>> cells = np.array([[0, 0, 0], [1, 0, 0], [0, 2, 1]])
    >>> m = LatentMap(np.eye(3, dtype=np.float32), kind="voxels", positions=cells * 0.1,
    ...               grid_index=cells, voxel_size=0.1)
    >>> folder = tempfile.mkdtemp()
    >>> write_vlmaps_map(m, folder).name
    'vlmaps_cam.h5df'
    >>> read_map(folder).source["up"]
    '+y'
    """
    from ..core.atomic import atomic_write, refuse_own_input
    from ._vlmaps import import_h5py

    where = lmap.source.get("path", "the map")
    if lmap.grid_index is None or lmap.voxel_size is None:
        raise UsageError(
            f"{where}: --format vlmaps needs a voxel grid (the map's 'grid_index' and "
            "'voxel_size'); this map has none, so it has no VLMaps cells. Convert a voxel "
            "map (a VLMaps or quash make-scene map), or write --format npz instead."
        )
    if lmap.positions is None:
        raise UsageError(f"{where}: --format vlmaps needs positions; this map has none.")
    h5py = import_h5py()
    n, d = lmap.n, lmap.dim
    cs = float(lmap.voxel_size)
    if float(np.float32(cs)) == cs:  # a float32 0.05 is stored as 0.05, not 0.0500000007
        cs = float(str(np.float32(cs)))
    up = lmap.source.get("up", "+z")
    if up not in TO_Y_UP:
        raise UsageError(
            f"{where}: the map's up axis (source['up']) is {up!r}, not one of "
            f"{', '.join(TO_Y_UP)}; fix the adapter that read it."
        )
    idx = _to_y_up(np.asarray(lmap.grid_index, dtype=np.int64).reshape(n, 3), up)
    pos = _to_y_up(np.asarray(lmap.positions, dtype=np.float64).reshape(n, 3), up)
    grid_pos, pcd_min = _cells_of(idx, pos, cs, up, where, lmap.source)
    shape = (grid_pos.max(axis=0) + 1) if n else np.ones(3, np.int64)
    pcd_max = pcd_min + (shape - 1) * cs
    occupied = -np.ones(tuple(int(s) for s in shape), dtype=np.int32)
    if n:
        occupied[grid_pos[:, 0], grid_pos[:, 1], grid_pos[:, 2]] = np.arange(n, dtype=np.int32)
        if int((occupied >= 0).sum()) != n:
            raise UsageError(
                f"{where}: two or more rows share a voxel (grid_index); VLMaps stores one "
                "row per cell. Merge them first."
            )
    kind = np.dtype(lmap.embeddings.dtype)
    feat_dtype = np.float16 if kind == np.float16 else np.float32
    colors = (
        np.full((n, 3), 128, np.uint8)
        if lmap.colors is None
        else np.asarray(lmap.colors, dtype=np.uint8).reshape(n, 3)
    )
    folder = Path(folder).expanduser()
    h5_path, names_path = vlmaps_outputs(folder)
    for out in (h5_path, names_path):
        refuse_own_input(out, lmap.source)
    labels = None if lmap.labels is None else np.asarray(lmap.labels, dtype=np.int64)
    if labels is not None and lmap.label_names:
        text = "".join(f"{i}: {i}, {name}\n" for i, name in enumerate(lmap.label_names))
        with atomic_write(names_path) as tmp:
            tmp.write_text(text, encoding="utf-8")
    with atomic_write(h5_path, suffix=".h5df") as tmp, h5py.File(tmp, "w") as f:
        f.create_dataset("mapped_iter_list", data=np.zeros(0, dtype=np.int32))
        feat = f.create_dataset("grid_feat", shape=(n, d), dtype=feat_dtype)
        for start in range(0, n, chunk_rows):
            stop = min(n, start + chunk_rows)
            feat[start:stop] = np.asarray(lmap.embeddings[start:stop], dtype=feat_dtype)
        f.create_dataset("grid_pos", data=grid_pos)
        f.create_dataset("weight", data=np.ones(n, dtype=np.float32))
        f.create_dataset("occupied_ids", data=occupied)
        f.create_dataset("grid_rgb", data=colors)
        f.create_dataset("pcd_min", data=pcd_min.astype(np.float64))
        f.create_dataset("pcd_max", data=pcd_max.astype(np.float64))
        f.create_dataset("cs", data=np.float64(cs))
        if labels is not None:
            f.create_dataset("grid_semantic", data=labels)
        for key in ENCODER_KEYS:
            if isinstance(lmap.source.get(key), str):
                f.attrs[key] = lmap.source[key]
    if not (labels is not None and lmap.label_names) and names_path.is_file():
        # the names of a map written here before would be read as this map's
        names_path.unlink()
        log.info("removed %s: it named the labels of the map this one replaces", names_path)
    log.info("wrote VLMaps map %s: %d cells x %d (%s up turned to +y)", h5_path, n, d, up)
    return h5_path


def _to_y_up(a: np.ndarray, up: str) -> np.ndarray:
    """``(N, 3)`` points or cells of a map whose up axis is ``up``, turned y-up."""
    return np.stack([sign * a[:, axis] for axis, sign in TO_Y_UP[up]], axis=1)


def _cells_of(
    idx: np.ndarray, pos: np.ndarray, cs: float, up: str, where: str, source: dict
) -> tuple[np.ndarray, np.ndarray]:
    """``(grid_pos, pcd_min)`` of turned cells ``idx`` and positions ``pos``, such that
    ``pcd_min + grid_pos * cs`` (what the ``vlmaps`` adapter reads back) are ``pos``.

    Cells are counted the way positions run: a grid whose index runs against its
    positions (VLMaps' mobile-base and 2023 top-down rows and columns, ``x = (gs/2 - row)
    * cs``) has that axis reversed, so every cell keeps its neighbours and its place.
    ``pcd_min`` is the midrange of ``pos - grid_pos * cs``, rounded to the micrometre.
    Positions off their cells are refused (a :class:`UsageError` naming the field and
    the fix) unless each lies inside its cell, where the file stores the cell's centre
    (voxel rounding, with a warning); VLMaps' own cell centres (``positions: centre``),
    which are exact or not representable at all, must be exact.
    """
    n = len(idx)
    if not n:
        return np.zeros((0, 3), np.int32), np.zeros(3)
    grid = np.empty((n, 3), dtype=np.int64)
    pcd_min = np.zeros(3)
    for a in range(3):
        best: tuple[float, np.ndarray, float] | None = None
        for sign in (1, -1):  # +1 first: it wins a tie (one layer, as a top-down grid's)
            j = sign * idx[:, a]
            j = j - j.min()
            rest = pos[:, a] - j * cs
            lo, hi = float(rest.min()), float(rest.max())
            if best is None or hi - lo < best[0]:
                best = (hi - lo, j, (lo + hi) / 2)
        assert best is not None
        _, grid[:, a], pcd_min[a] = best
    # The midrange carries float rounding (3e-9 for an origin of 0); micrometres are far
    # below any cell size and read back as the round number the source meant.
    pcd_min = np.round(pcd_min, 6) + 0.0
    off = np.abs(pcd_min + grid * cs - pos).max(axis=0)
    # float32 positions carry their own rounding, relative to their size
    tol = max(1e-3 * cs, 8 * float(np.finfo(np.float32).eps) * float(np.abs(pos).max()))
    if (off <= tol).all():
        return grid.astype(np.int32), pcd_min
    worst = int(np.argmax(off))
    axis = "xyz"[TO_Y_UP[up][worst][0]]
    far = float(off[worst])
    if source.get("positions") == "centre":  # read by a VLMaps adapter from its cells
        raise UsageError(
            f"{where}: field 'positions' cannot be written to a VLMaps camera-base file: "
            "they are the centres of VLMaps' mobile-base (or 2023 top-down) cells, which "
            "are not evenly spaced (VLMaps' truncating bins make the cell at the origin two "
            "cells wide: centres ..., -1.5, 0, 1.5, ... cells), so no pcd_min + grid_pos * "
            f"cs holds them (up to {far:.3g} m off along the source's {axis}). Read the map "
            "with VLMaps' own evenly spaced positions (its grid_id2base_pos_3d or "
            "grid_id2pos, the cell face nearest the origin): quash convert SRC DST --format "
            "vlmaps -o positions=upstream (read_map(src, positions='upstream')); or write "
            "--format npz, which keeps these positions."
        )
    if far > 0.5 * cs - tol:
        raise UsageError(
            f"{where}: fields 'positions' and 'grid_index' disagree: positions lie up to "
            f"{far:.3g} m from their cells along the source's {axis}, more than half a "
            f"cell (voxel_size {cs:g}), so a VLMaps file (positions read back as pcd_min + "
            "grid_pos * cs) would move them to other places. Make grid_index the cells "
            "of positions (round(positions / voxel_size), its axes in positions' order), "
            "or write --format npz, which keeps both as they are. A VLMaps mobile-base or "
            "top-down map read with cell centres converts with -o positions=upstream."
        )
    log.warning(
        "%s: positions are not at their cell centres (up to %.3g m off along the source's "
        "%s, inside their cells); the VLMaps file stores the cell centres (pcd_min + "
        "grid_pos * cs)",
        where,
        far,
        axis,
    )
    return grid.astype(np.int32), pcd_min
