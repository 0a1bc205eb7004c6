"""``vlmaps-2d``: the 2023 VLMaps top-down grids (``map/grid_lseg_1.npy``).

VLMaps' original release (``create_lseg_map_batch``) writes, in ``<scene>/map/``:

========================== =============== ========================================
``grid_lseg_1.npy``        (gs, gs, D) f32 averaged LSeg features; zero = unobserved
``color_top_down_1.npy``   (gs, gs, 3) u8  top-down colour
``grid_1_gt.npy``          (gs, gs) int32  ground-truth class id (-1 = void)
``obstacles.npy``          (gs, gs) u8     1 free, 0 obstacle
``weight_lseg_1.npy``      (gs, gs) f64    fusion weight
========================== =============== ========================================

with ``gs = 1000`` and ``cs = 0.05`` (the defaults of ``create_lseg_map_batch``). A
point at ``(x, z)`` of the first camera frame (x right, z forward) lands in column
``int(gs/2 + int(x/cs))`` and row ``int(gs/2 - int(z/cs))``; ``int`` truncates toward
zero, so the cells at the origin row and column are two cells wide and every other
cell's centre lies half a cell further from the origin than the nearest face.

We report each cell in the same right-handed, z-up frame as the 3D mobile-base maps
(x forward = camera z, y left = -camera x, z = 0), at the cell centre by default:
``x = (k + 0.5 * sign(k)) * cs`` with ``k = gs//2 - row``, and likewise ``y`` with
``k = gs//2 - col``. ``positions="upstream"`` gives VLMaps' own ``grid_id2pos``
instead (``x = (gs/2 - row) * cs``, ``y = (gs/2 - col) * cs``: the face nearest the
origin). The grid size is the file's; ``cs`` is not stored (option, default 0.05).

Design choices:

* ``kind = "voxels"`` with ``grid_index = (row, col, 0)`` and ``voxel_size = cs``: the map
  is one flat layer of cells, so instance grouping uses grid connectivity (8-neighbour
  in the plane) and viewers draw cells as boxes. ``"pixels"`` would require every cell
  of the grid to be an item, which defeats dropping unobserved cells.
* Only observed (non-zero) cells become items. The grid is opened with
  ``np.load(mmap_mode="r")``; non-zero cells are found in row blocks, and the map's
  embeddings are a lazy :class:`~quash_plugins.adapters._vlmaps_common.RowSubset` of the
  memory map, so the grid is never loaded whole. ``keep_empty=True`` keeps all
  ``gs * gs`` cells (zero rows never match). A grid with no observed cell is an empty
  map (0 items).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.interfaces import MapAdapter
from ..core.types import LatentMap, record_inputs
from ._npy import load_npy
from ._vlmaps_common import (
    RowSubset,
    cell_centres,
    check_labels,
    find_obj2cls,
    fit_label_names,
    load_label_names,
    rgb_to_uint8,
)
from ._vlmaps_options import (
    CS_FIX,
    DEFAULT_CS,
    check_positions_option,
    option_number,
)

log = logging.getLogger(__name__)

GRID = "grid_lseg_1.npy"
COLOR = "color_top_down_1.npy"
GT = "grid_1_gt.npy"
OBSTACLES = "obstacles.npy"


def resolve_grid(source: Any) -> Path | None:
    """``grid_lseg_*.npy`` for a path to the file, its ``map/`` folder or the scene folder."""
    if not isinstance(source, (str, Path)):
        return None
    p = Path(source).expanduser()
    if p.is_file():
        return p if p.suffix == ".npy" else None
    for folder in (p, p / "map"):
        if (folder / GRID).is_file():
            return folder / GRID
        if folder.is_dir():
            hits = sorted(folder.glob("grid_lseg_*.npy"))
            if len(hits) == 1:
                return hits[0]
    return None


def _sibling(grid: Path, stem: str) -> Path:
    """The companion file matching ``grid``'s mask version (``_1`` by default)."""
    version = grid.stem.removeprefix("grid_lseg_")
    name = stem.replace("_1", f"_{version}") if version and version != "1" else stem
    return grid.with_name(name)


class VLMaps2DAdapter(MapAdapter):
    """Read a 2023 VLMaps top-down map (``grid_lseg_1.npy`` and its companions).

    Parameters
    ----------
    cs
        Cell size in metres (VLMaps default 0.05).
    label_names
        Names of the ``grid_1_gt.npy`` class ids (file or in-memory list/mapping; see
        :func:`~quash_plugins.adapters._vlmaps_common.load_label_names`). Default: the
        scene's ``obj2cls_dict.txt`` if present.
    keep_empty
        Keep unobserved (all-zero) cells as items instead of dropping them.
    positions
        ``"centre"`` (default): cell centres. ``"upstream"``: VLMaps' own ``grid_id2pos``
        (the cell face nearest the origin).
    block_rows
        Grid rows scanned per block when finding observed cells.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> a = VLMaps2DAdapter()
    >>> m = a.read(a.write_example(pathlib.Path(tempfile.mkdtemp())))
    >>> m.kind, float(m.positions[:, 2].max())
    ('voxels', 0.0)
    """

    name = "vlmaps-2d"
    priority = 20
    file_names = ("grid_lseg_*.npy",)

    def __init__(
        self,
        cs: float = DEFAULT_CS,
        label_names: Any = None,
        keep_empty: bool = False,
        positions: str = "centre",
        block_rows: int = 64,
    ) -> None:
        self.cs = cs
        self.label_names = label_names
        self.keep_empty = keep_empty
        self.positions = positions
        self.block_rows = block_rows

    def sniff(self, source: Any) -> bool:
        try:
            grid = resolve_grid(source)
            if grid is None:
                return False
            arr = np.load(grid, mmap_mode="r", allow_pickle=False)
            return arr.ndim == 3 and arr.shape[0] == arr.shape[1] and arr.dtype.kind == "f"
        except Exception:  # noqa: BLE001 - sniff never raises
            return False

    def unrecognised_hint(self, source: Any) -> str:
        """For a ``map/`` folder or scene whose grid numpy cannot read (a copy cut short):
        the grid is named with the adapter that says why."""
        try:
            grid = resolve_grid(source)
            if grid is None or self.sniff(grid):
                return ""
            return (
                f"{grid} is named as VLMaps' 2023 grid but is not a readable (gs, gs, D) "
                "array: --adapter vlmaps-2d says why."
            )
        except Exception:  # noqa: BLE001 - a hint never raises
            return ""

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        opts["positions"] = check_positions_option(opts["positions"], self.name)
        grid_path = resolve_grid(source)
        if grid_path is None:
            raise MapFormatError(
                f"{source}: no {GRID} found. Pass the .npy file or the map/ folder that holds it."
            )
        where = str(grid_path)
        cs = option_number(opts["cs"], "cs", where, CS_FIX)  # the grids store no cell size
        grid = _load_npy(grid_path)
        if grid.ndim != 3 or grid.shape[0] != grid.shape[1]:
            raise MapFormatError(
                f"{where}: the feature grid must have shape (gs, gs, D); got {grid.shape}."
            )
        if grid.dtype.kind not in "fiu":
            raise MapFormatError(f"{where}: the feature grid must hold numbers; got {grid.dtype}.")
        gs, _, d = (int(x) for x in grid.shape)
        if gs == 0 or d == 0:
            raise MapFormatError(f"{where}: the feature grid is empty (shape {grid.shape}).")
        flat = grid.reshape(gs * gs, d)  # a view of the memory map, not a copy
        observed = _observed_cells(grid, where, int(opts["block_rows"]))
        index = np.arange(gs * gs, dtype=np.int64) if opts["keep_empty"] else observed
        embeddings: Any = flat if opts["keep_empty"] else RowSubset(flat, index)
        rows, cols = np.divmod(index, gs)
        positions = np.zeros((len(index), 3), dtype=np.float32)
        if opts["positions"] == "upstream":  # grid_id2pos, turned into the base frame
            positions[:, 0] = (gs / 2.0 - rows) * cs
            positions[:, 1] = (gs / 2.0 - cols) * cs
        else:
            positions[:, 0] = cell_centres(gs // 2 - rows, cs)
            positions[:, 1] = cell_centres(gs // 2 - cols, cs)
        grid_index = np.stack([rows, cols, np.zeros_like(rows)], axis=1)

        colors = labels = None
        color_path = _sibling(grid_path, COLOR)
        if color_path.is_file():
            rgb = _load_npy(color_path, "color")
            _expect(rgb, (gs, gs, 3), color_path, "colour grid")
            colors = rgb_to_uint8(rgb.reshape(gs * gs, 3)[index], str(color_path), "colour grid")
        gt_path = _sibling(grid_path, GT)
        if gt_path.is_file():
            gt = _load_npy(gt_path, "gt")
            _expect(gt, (gs, gs), gt_path, "ground-truth grid")
            labels = check_labels(gt.reshape(gs * gs)[index], len(index), str(gt_path), "gt")
        obstacles_path = grid_path.with_name(OBSTACLES)
        source: dict[str, Any] = {
            "adapter": self.name,
            "path": where,
            "format": "vlmaps-2d",
            "up": "+z",  # the mobile-base frame, z = 0 (see the module's docstring)
            "gs": gs,
            "cs": cs,
            "observed_cells": int(observed.size),
            "positions": opts["positions"],
            "encoder_hint": f"lseg CLIP ViT-B/32 {d}" if d == 512 else f"{d}-d features",
        }
        if obstacles_path.is_file():
            obstacles = _load_npy(obstacles_path, "obstacles")
            _expect(obstacles, (gs, gs), obstacles_path, "obstacle grid")
            source["obstacles"] = str(obstacles_path)
        names_spec = opts["label_names"]
        if names_spec is None and labels is not None:
            names_spec = find_obj2cls(grid_path.parent, levels=1)
        names = fit_label_names(load_label_names(names_spec), labels, names_spec, gt_path)
        read = [p for p in (color_path, gt_path, obstacles_path) if p.is_file()]
        record_inputs(source, *read, names_spec)  # the companions read beside the grid
        return LatentMap(
            embeddings=embeddings,
            kind="voxels",
            positions=positions,
            colors=colors,
            labels=labels,
            label_names=names,
            voxel_size=cs,
            grid_index=grid_index,
            normalize=True,
            source=source,
        )

    def write_example(self, directory: Path) -> Path:
        """A small ``map/`` folder written the way ``create_lseg_map_batch`` writes it."""
        rng = np.random.default_rng(0)
        folder = Path(directory) / "map"
        folder.mkdir(parents=True, exist_ok=True)
        gs, d = 24, 8
        grid = np.zeros((gs, gs, d), dtype=np.float32)
        seen = rng.random((gs, gs)) < 0.4
        grid[seen] = rng.normal(size=(int(seen.sum()), d)).astype(np.float32)
        color = np.zeros((gs, gs, 3), dtype=np.uint8)
        color[seen] = rng.integers(0, 256, (int(seen.sum()), 3), dtype=np.uint8)
        gt = np.zeros((gs, gs), dtype=np.int32)
        gt[seen] = rng.integers(0, 3, int(seen.sum()))
        obstacles = np.ones((gs, gs), dtype=np.uint8)
        obstacles[seen] = 0
        for name, arr in ((GRID, grid), (COLOR, color), (GT, gt), (OBSTACLES, obstacles)):
            with open(folder / name, "wb") as fh:
                np.save(fh, arr)
        return folder


def _load_npy(path: Path, name: str = "grid") -> np.ndarray:
    return load_npy(path, name=name, again="copy or create")


def _expect(arr: np.ndarray, shape: tuple[int, ...], path: Path, what: str) -> None:
    if arr.shape != shape:
        raise MapFormatError(f"{path}: the {what} must have shape {shape}; got {arr.shape}.")


def _observed_cells(grid: np.ndarray, where: str, block_rows: int) -> np.ndarray:
    """Sorted flat indices of non-zero cells, found in blocks of grid rows.

    Also rejects NaN/Inf. Memory: one block of ``block_rows * gs * D`` values.
    """
    gs, _, d = grid.shape
    block_rows = max(1, block_rows)
    found = []
    for r0 in range(0, gs, block_rows):
        try:
            block = np.asarray(grid[r0 : r0 + block_rows])
        except (OSError, ValueError) as exc:
            raise MapFormatError(f"{where}: cannot read grid rows from {r0} ({exc}).") from None
        if block.dtype.kind == "f" and not np.isfinite(block).all():
            r, c = np.argwhere(~np.isfinite(block).all(axis=-1))[0]
            raise MapFormatError(
                f"{where}: the feature grid contains NaN or Inf (first at cell "
                f"row {r0 + int(r)}, col {int(c)})."
            )
        nz = np.flatnonzero(block.any(axis=-1))
        found.append(nz + r0 * gs)
    return np.concatenate(found) if found else np.empty(0, dtype=np.int64)


def to_vlmaps_grid(values: Any, lmap: LatentMap, fill: Any = None) -> np.ndarray:
    """Put a per-row vector of a ``vlmaps-2d`` map back on VLMaps' ``(gs, gs)`` grid.

    ``values`` is ``(N,)`` (a query's ``mask`` or ``scores``) or ``(Q, N)`` (the
    ``masks``/``scores`` of ``quash query --out``), one entry per row of ``lmap``, which
    is in the order of the map's ``grid_index``. Returns ``(gs, gs)`` (or ``(Q, gs, gs)``)
    indexed ``[row, col]`` like ``grid_lseg_1.npy``; cells that are not rows of the map
    (unobserved) get ``fill``: ``False`` for bool values, NaN for scores, unless given.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> a = VLMaps2DAdapter()
    >>> lmap = a.read(a.write_example(pathlib.Path(tempfile.mkdtemp())))
    >>> grid = to_vlmaps_grid(np.ones(lmap.n, bool), lmap)
    >>> grid.shape, int(grid.sum()) == lmap.n
    ((24, 24), True)
    """
    if lmap.source.get("format") != "vlmaps-2d" or lmap.grid_index is None:
        raise QuashError(
            f"{lmap.source.get('path', 'the map')}: to_vlmaps_grid needs a map read with the "
            f"'vlmaps-2d' adapter (map/grid_lseg_1.npy); this one was read with "
            f"{lmap.source.get('adapter', 'another adapter')!r}. For a 3D VLMaps map the rows "
            "are grid_feat's rows: grid_pos[mask] gives the voxels."
        )
    gs = int(lmap.source["gs"])
    arr = np.asarray(values)
    if arr.shape[-1:] != (lmap.n,) or arr.ndim not in (1, 2):
        raise QuashError(
            f"to_vlmaps_grid: values must have shape (N,) or (Q, N) with N = {lmap.n} (the "
            f"map's rows); got {arr.shape}."
        )
    if fill is None:
        fill = False if arr.dtype == bool else np.nan
    dtype = arr.dtype if arr.dtype == bool else np.result_type(arr.dtype, np.asarray(fill).dtype)
    out = np.full((*arr.shape[:-1], gs, gs), fill, dtype=dtype)
    rows, cols = lmap.grid_index[:, 0], lmap.grid_index[:, 1]
    out[..., rows, cols] = arr
    return out
