"""``openlex3d``: OpenLex3D's neutral prediction layout (and, opt-in, ConceptGraphs pickles).

OpenLex3D evaluates any method from a folder of three files:

- ``point_cloud.pcd``: the RGB point cloud, ``n_points`` points (read through open3d;
  ``pointcloud.pcd`` and ``input.ply`` are accepted too, as written by some converters).
- ``embeddings.npy``: ``(n_objects, D)`` features, one row per object (per point for
  dense methods).
- ``index.npy``: ``(n_points,)`` int; ``embeddings[index[i]]`` is the feature of point
  ``i``. Dense methods store ``np.arange(n_points)``.

The embeddings are memory-mapped. A dense map (``index == arange``) uses the memmap
directly; otherwise rows are gathered through the index block by block
(:class:`~quash_plugins.adapters._rows.IndexedRows`). A negative index marks a point
with no object: its row is zero, so it never matches. Rows are L2-normalised when read.
The memory maps (and an int64 ``index.npy``, kept memory-mapped too) pickle as their
file, offset, shape and dtype, so a Dask task graph does not carry the table.

Pickles (ConceptGraphs ``*.pkl.gz``) are never unpickled unless ``allow_pickle=True``:
unpickling runs code from the file. With the opt-in, ConceptGraphs' ``objects`` list is
read the same way (``clip_ft`` per object, ``pcd_np`` / ``pcd_color_np`` per point), and
its background objects (``bg_objects``) after them unless ``background=False``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import MapFormatError, QuashError
from ..core.interfaces import MapAdapter
from ..core.types import UP_AXES, LatentMap, record_inputs
from ._npy import load_npy
from ._npz import encoder_record
from ._rows import IndexedRows, colors_to_uint8, scan_finite, should_scan

log = logging.getLogger(__name__)

CLOUD_NAMES = ("point_cloud.pcd", "pointcloud.pcd", "point_cloud.ply", "input.ply")
PICKLE_SUFFIXES = (".pkl", ".pickle", ".pkl.gz", ".pickle.gz")


def is_pickle_path(source: Any) -> bool:
    return isinstance(source, (str, Path)) and str(source).lower().endswith(PICKLE_SUFFIXES)


def pickle_refusal(path: Path) -> MapFormatError:
    return MapFormatError(
        f"{path}: is a pickle (e.g. a ConceptGraphs map). Pickles are never loaded by default "
        "because unpickling runs code from the file. If you trust it, opt in with the "
        "'openlex3d' adapter option allow_pickle=True (config: adapter: {name: openlex3d, "
        "allow_pickle: true}; CLI: quash convert SRC DST.npz --allow-pickle), then keep the "
        "converted .npz."
    )


def _open3d():
    try:
        import open3d as o3d
    except ImportError:
        raise QuashError(
            'Reading point_cloud.pcd needs open3d: pip install "quash-plugins[open3d]"'
        ) from None
    return o3d


def _find_cloud(folder: Path) -> Path | None:
    for name in CLOUD_NAMES:
        if (folder / name).is_file():
            return folder / name
    return None


def _load_npy(path: Path, field: str) -> np.ndarray:
    if not path.is_file():
        raise MapFormatError(
            f"{path}: missing file; OpenLex3D predictions need point_cloud.pcd, "
            f"embeddings.npy and index.npy ({field})."
        )
    return load_npy(path, field, name=field, again="copy or export")


class OpenLex3DAdapter(MapAdapter):
    """Read OpenLex3D's ``point_cloud.pcd`` + ``embeddings.npy`` + ``index.npy`` folder.

    Parameters
    ----------
    allow_pickle
        Allow reading ConceptGraphs ``.pkl`` / ``.pkl.gz`` files. Only for files you trust.
    background
        For a ConceptGraphs pickle: read its background objects (``bg_objects``: wall,
        floor, ceiling) as map items after its ``objects`` (default True), or leave them
        out (False; an INFO line says how many).
    check_finite
        Scan the embeddings for NaN/Inf while reading: True, False or ``"auto"`` (only up
        to ``finite_check_mb``; larger maps are checked block by block at query time).
    finite_check_mb
        Size limit of the ``"auto"`` scan, in MiB.

    Examples
    --------
    >>> from quash_plugins import registry
    >>> lmap = registry.create("adapters", "openlex3d").read("preds/replica/office0")  # doctest: +SKIP
    """

    name = "openlex3d"
    priority = 40

    def __init__(
        self,
        allow_pickle: bool = False,
        background: bool = True,
        check_finite: bool | str = "auto",
        finite_check_mb: float = 512.0,
    ) -> None:
        self.allow_pickle = allow_pickle
        self.background = background
        self.check_finite = check_finite
        self.finite_check_mb = finite_check_mb

    def sniff(self, source: Any) -> bool:
        try:
            if not isinstance(source, (str, Path)):
                return False
            p = Path(source)
            if p.is_file():
                return is_pickle_path(p) or (p.name in CLOUD_NAMES and self.sniff(p.parent))
            return (
                p.is_dir()
                and (p / "embeddings.npy").is_file()
                and (p / "index.npy").is_file()
                and _find_cloud(p) is not None
            )
        except OSError:
            return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        opts = self.options(options)
        path = Path(source).expanduser()
        if is_pickle_path(path):
            if not opts["allow_pickle"]:
                raise pickle_refusal(path)
            from ._conceptgraphs import read_conceptgraphs

            return read_conceptgraphs(path, background=opts["background"])
        folder = path.parent if path.is_file() else path
        if not folder.is_dir():
            raise MapFormatError(f"Map not found: {path}")
        cloud = _find_cloud(folder)
        if cloud is None:
            raise MapFormatError(
                f"{folder / 'point_cloud.pcd'}: missing file; OpenLex3D predictions need "
                f"point_cloud.pcd, embeddings.npy and index.npy (the cloud may also be named "
                f"{', '.join(CLOUD_NAMES[1:])})."
            )
        table = _load_npy(folder / "embeddings.npy", "embeddings")
        index = _load_npy(folder / "index.npy", "index")
        emb_label, idx_label = folder / "embeddings.npy", folder / "index.npy"
        if table.ndim != 2:
            raise MapFormatError(
                f"{emb_label}: field 'embeddings' must be 2-D (n_objects, D); got shape {table.shape}."
            )
        if table.shape[1] == 0:
            raise MapFormatError(
                f"{emb_label}: field 'embeddings' has no feature dimension (shape {table.shape})."
            )
        if table.dtype.kind not in "fiu":
            raise MapFormatError(
                f"{emb_label}: field 'embeddings' must hold numbers; got {table.dtype}."
            )
        if index.ndim != 1:
            raise MapFormatError(
                f"{idx_label}: field 'index' must be 1-D (n_points,); got shape {index.shape}."
            )
        checked = self._check_index(np.asarray(index), idx_label, table.shape[0])
        # an int64 index.npy stays memory-mapped (a Dask task reopens it by path)
        index = index if checked.size and index.dtype == np.dtype("<i8") else checked

        positions, colors = self._read_cloud(cloud)
        if len(positions) != len(index):
            raise MapFormatError(
                f"{idx_label}: field 'index' has {len(index)} entries but {cloud.name} has "
                f"{len(positions)} points; row counts must match."
            )
        if should_scan(
            opts["check_finite"], table.size * table.dtype.itemsize, opts["finite_check_mb"]
        ):
            scan_finite(table, str(emb_label), "embeddings")
        dense = len(index) == table.shape[0] and np.array_equal(index, np.arange(len(index)))
        embeddings = table if dense else IndexedRows(table, index)
        return LatentMap(
            embeddings=embeddings,
            kind="points",
            positions=positions,
            colors=colors,
            normalize=True,
            source=record_inputs(  # the folder: every file read is in it
                {
                    "adapter": self.name,
                    "path": str(folder),
                    "cloud": cloud.name,
                    "objects": int(table.shape[0]),
                    "dense": bool(dense),
                    **_exported_record(folder),
                }
            ),
        )

    @staticmethod
    def _check_index(index: np.ndarray, label: Path, n_objects: int) -> np.ndarray:
        if index.size == 0:  # an empty map (0 points)
            return np.zeros(0, dtype=np.int64)
        if index.dtype.kind == "f":
            if not np.isfinite(index).all() or not np.array_equal(index, np.round(index)):
                raise MapFormatError(
                    f"{label}: field 'index' must hold integers; got non-integral floats."
                )
        elif index.dtype.kind not in "iu":
            raise MapFormatError(f"{label}: field 'index' must hold integers; got {index.dtype}.")
        index = index.astype(np.int64)
        fix = (
            f"each entry is a row of embeddings.npy (0 to {n_objects - 1}) or -1 for no "
            "object; a dense map stores np.arange(n_points)"
        )
        low = int(index.min())
        if low < -1:
            raise MapFormatError(f"{label}: field 'index' holds {low}; {fix}.")
        top = int(index.max())
        if top >= n_objects:
            raise MapFormatError(
                f"{label}: field 'index' refers to row {top}, but embeddings.npy has only "
                f"{n_objects} rows; {fix}."
            )
        return index

    @staticmethod
    def _read_cloud(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
        o3d = _open3d()
        if path.suffix.lower() == ".pcd":
            _check_binary_pcd_size(path)
        pcd = o3d.io.read_point_cloud(str(path))
        points = np.asarray(pcd.points, dtype=np.float32).reshape(-1, 3)
        if not np.isfinite(points).all():
            bad = int(np.argwhere(~np.isfinite(points))[0][0])
            raise MapFormatError(
                f"{path}: field 'points' contains NaN or Inf (first at point {bad})."
            )
        colors = None
        if pcd.has_colors():
            colors = colors_to_uint8(np.asarray(pcd.colors), str(path), "0-1")
        return points, colors

    def write_example(self, directory: Path) -> Path:
        """Write an object-level OpenLex3D folder (5 objects, 50 points, one unassigned)."""
        rng = np.random.default_rng(0)
        folder = Path(directory) / "openlex3d-example"
        points = rng.uniform(-1, 1, size=(50, 3))
        colors = rng.uniform(0, 1, size=(50, 3))
        index = rng.integers(0, 5, size=50)
        index[0] = -1
        write_openlex3d(folder, points, colors, rng.normal(size=(5, 12)).astype(np.float32), index)
        return folder


def write_openlex3d(
    folder: str | Path,
    points: np.ndarray,
    colors: np.ndarray | None,
    embeddings: np.ndarray,
    index: np.ndarray,
) -> Path:
    """Write OpenLex3D's layout: ``point_cloud.pcd`` (colours 0-1), ``embeddings.npy``, ``index.npy``."""
    o3d = _open3d()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    pcd = o3d.geometry.PointCloud()
    pcd.points = o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64))
    if colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(np.asarray(colors, dtype=np.float64))
    o3d.io.write_point_cloud(str(folder / "point_cloud.pcd"), pcd)
    np.save(folder / "embeddings.npy", np.asarray(embeddings))
    np.save(folder / "index.npy", np.asarray(index))
    return folder


# ---------------------------------------------------------------------------------------
# Export: any map as OpenLex3D's prediction layout (``quash convert --format openlex3d``)

#: Written beside the triple: where it came from, and the mark that lets a later export
#: replace the folder.
EXPORT_MARKER = "quash_export.json"
PCD_POINT = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])
PCD_POINT_XYZ = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


def _check_binary_pcd_size(path: Path) -> None:
    """Refuse a binary PCD shorter than its header says: open3d reads one cut short (an
    interrupted copy) as no points, or as as many points of whatever memory held."""
    with open(path, "rb") as f:
        head = f.read(4096)
    fields: dict[str, list[str]] = {}
    end = 0
    for line in head.split(b"\n")[:-1]:
        end += len(line) + 1
        words = line.decode("ascii", "replace").split()
        if words and not words[0].startswith("#"):
            fields[words[0].upper()] = words[1:]
        if words[:1] == ["DATA"]:
            break
    else:
        if len(head) < 4096 and "FIELDS" in fields:  # the whole file: its header cut short
            raise MapFormatError(
                f"{path}: field 'points' is cut short: the file ends ({len(head)} bytes) "
                "before its header's DATA line. It is damaged or truncated (an interrupted "
                "copy): copy or export it again."
            )
        return  # no DATA line in the first 4 kB: left to open3d
    try:
        if fields["DATA"] != ["binary"]:
            return
        row = sum(int(a) * int(b) for a, b in zip(fields["SIZE"], fields["COUNT"]))
        expected = end + int(fields["POINTS"][0]) * row
    except (KeyError, IndexError, ValueError):
        return
    size = path.stat().st_size
    if size < expected:
        raise MapFormatError(
            f"{path}: field 'points' is cut short: its header says {fields['POINTS'][0]} "
            f"points ({expected} bytes), the file holds {size} bytes. It is damaged or "
            "truncated (an interrupted copy): copy or export it again."
        )


def pcd_header(n: int, colors: bool) -> bytes:
    """A binary PCD v0.7 header (the layout open3d writes: x y z float32, packed rgb)."""
    fields = "x y z rgb" if colors else "x y z"
    size = "4 4 4 4" if colors else "4 4 4"
    types = "F F F U" if colors else "F F F"
    count = "1 1 1 1" if colors else "1 1 1"
    return (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        f"FIELDS {fields}\nSIZE {size}\nTYPE {types}\nCOUNT {count}\n"
        f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    ).encode("ascii")


def write_pcd(
    path: str | Path, points: np.ndarray, colors: np.ndarray | None = None, chunk: int = 1 << 20
) -> Path:
    """Write a binary PCD file: ``points (N, 3)`` metres, optional ``colors (N, 3)`` uint8.

    Our own writer (no open3d needed, exact uint8 colours, empty clouds allowed, written
    in chunks); its output is the layout open3d itself writes and reads: fields
    ``x y z rgb``, float32 coordinates, colour packed as ``r << 16 | g << 8 | b``.
    """
    points = np.asarray(points)
    n = len(points)
    if points.shape != (n, 3):
        raise ValueError(f"points must be (N, 3); got {points.shape}")
    if colors is not None:
        colors = np.asarray(colors, dtype=np.uint8)
        if colors.shape != (n, 3):
            raise ValueError(f"colors must be (N, 3) like the points; got {colors.shape}")
    path = Path(path)
    with open(path, "wb") as fh:
        fh.write(pcd_header(n, colors is not None))
        for start in range(0, n, chunk):
            stop = min(n, start + chunk)
            rec = np.empty(stop - start, PCD_POINT if colors is not None else PCD_POINT_XYZ)
            p = np.asarray(points[start:stop], dtype=np.float32)
            rec["x"], rec["y"], rec["z"] = p[:, 0], p[:, 1], p[:, 2]
            if colors is not None:
                c = colors[start:stop].astype(np.uint32)
                rec["rgb"] = (c[:, 0] << 16) | (c[:, 1] << 8) | c[:, 2]
            fh.write(rec.tobytes())
    return path


def _exported_record(folder: Path) -> dict[str, str]:
    """What a quash export (``quash_export.json``) says of its map: the encoder record
    of its ``source``, and its ``up`` axis (older exports: the ``source``'s), if any."""
    import json

    marker = folder / EXPORT_MARKER
    if not marker.is_file():
        return {}
    try:
        meta = json.loads(marker.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        log.warning(
            "%s: not readable JSON (cut short?); the map's encoder record and up axis it "
            "holds are ignored, so +z is taken as up: give --up (or export the map again) "
            "if it is not z-up",
            marker,
        )
        return {}
    meta = meta if isinstance(meta, dict) else {}
    recorded = meta.get("source") if isinstance(meta.get("source"), dict) else {}
    out = encoder_record(recorded)
    up = meta.get("up", recorded.get("up"))
    if up is not None and up not in UP_AXES:
        raise MapFormatError(
            f"{marker}: field 'up' is {up!r}, not an up axis; write one of "
            f"{', '.join(UP_AXES)} (or remove it: +z is assumed)."
        )
    if up is not None:
        out["up"] = up
    return out


def is_openlex3d_export(path: str | Path) -> bool:
    """True for a folder written by :func:`write_openlex3d_map` (it may be replaced)."""
    p = Path(path)
    return p.is_dir() and (p / EXPORT_MARKER).is_file()


def check_openlex3d_exportable(lmap: LatentMap, hint: str = "") -> None:
    """Refuse (:class:`UsageError`) a map that OpenLex3D's folder cannot hold: one without
    positions (a pixel map), since ``point_cloud.pcd`` needs one 3D point per item.
    ``quash convert --format openlex3d`` and ``quash query --format openlex3d`` both ask
    it, the latter before any query is answered; ``hint`` ends the message."""
    from ..core.errors import UsageError

    if lmap.positions is None:
        raise UsageError(
            f"{lmap.source.get('path', 'the map')} has no positions (a pixel map?); "
            f"OpenLex3D's point_cloud.pcd needs one 3D point per item.{hint}"
        )


def write_openlex3d_map(lmap: LatentMap, folder: str | Path, chunk_rows: int = 65536) -> Path:
    """Write ``lmap`` as OpenLex3D's prediction folder, atomically.

    ``embeddings.npy`` float32 (values as stored, not normalised: OpenLex3D takes
    cosines), ``index.npy`` int64, ``point_cloud.pcd`` (the map's positions and colours)
    and ``quash_export.json`` (provenance, and the map's ``up`` axis when its
    ``source`` records one; the adapter reads it back). A map of objects (rows gathered through an
    index: ConceptGraphs, a sparse OpenLex3D folder, OpenScene's 2D-3D features) keeps
    its objects: ``embeddings.npy`` is its ``(M, D)`` table and ``index.npy`` its
    point-to-object index, so OpenLex3D ranks objects, not single points. Points of no
    object (index -1, which OpenLex3D would read as the last row) point to one extra
    zero row. Any other map is dense: ``(N, D)`` and ``arange(N)``. Embeddings are
    copied ``chunk_rows`` rows at a time. The folder is written beside ``folder`` and
    renamed into place; an existing ``folder`` is replaced only when it is a previous
    export.
    """
    import json

    from ..core.atomic import atomic_dir
    from ..core.progress import progress

    folder = Path(folder).expanduser()
    check_openlex3d_exportable(lmap)
    n, d = lmap.n, lmap.dim
    rows, index = lmap.embeddings, np.arange(n, dtype=np.int64)
    dense = not isinstance(rows, IndexedRows)
    if not dense:
        rows, index = rows.table, np.asarray(rows.index, dtype=np.int64)
    stored = int(rows.shape[0])
    m = stored
    if (index < 0).any():  # no object: one zero row after the table, never -1 (the last row)
        index = np.where(index < 0, stored, index)
        m += 1
    kind = f"OpenLex3D export of quash (with {EXPORT_MARKER})"
    with atomic_dir(folder, replaceable=is_openlex3d_export, kind=kind) as tmp:
        tmp.mkdir()
        out = np.lib.format.open_memmap(tmp / "embeddings.npy", "w+", np.float32, (m, d))
        with progress(stored, f"writing {Path(folder).name}/embeddings.npy") as advance:
            for start in range(0, stored, chunk_rows):
                stop = min(stored, start + chunk_rows)
                out[start:stop] = np.asarray(rows[start:stop], dtype=np.float32)
                advance(stop - start)
        out[stored:] = 0.0
        out.flush()
        del out
        np.save(tmp / "index.npy", index)
        write_pcd(tmp / "point_cloud.pcd", lmap.positions, lmap.colors)
        meta = {
            "format": "openlex3d-predictions",
            "written_by": "quash-plugins",
            "n_points": n,
            "n_rows": m,
            "dim": d,
            "dense": dense,
            **({"up": lmap.source["up"]} if lmap.source.get("up") in UP_AXES else {}),
            "source": {k: v for k, v in lmap.source.items() if isinstance(v, (str, int, float))},
        }
        (tmp / EXPORT_MARKER).write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    log.info("wrote OpenLex3D predictions %s: %d points, %d rows x %d", folder, n, m, d)
    return folder
