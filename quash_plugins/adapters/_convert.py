"""Convert any readable map to quash-plugins' portable NPZ (or a Zarr store).

:func:`convert_map` reads with any adapter and writes atomically. In-memory maps go
through :func:`~quash_plugins.adapters._npz.write_npz_map`; lazy maps (HDF5 datasets,
per-frame feature maps, memmaps gathered through an index) are streamed into the NPZ
block by block by :func:`write_npz_streaming`, so the map is never held whole.

Pixel maps keep their frames as three extra arrays (``frame_ids (F,) str``,
``frame_hw (F, 2) int64``, ``frame_offsets (F,) int64``), which :func:`frames_from_npz`
turns back into :class:`~quash_plugins.core.types.FrameInfo`; :func:`frames_from_zarr`
reads them from a zarr result store (attributes of the same names) or zarr map;
:func:`up_from_npz` and :func:`up_from_zarr` read the up axis of their positions. Their
layout is defined once, in :mod:`quash_plugins.core.layout`.
"""

from __future__ import annotations

import logging
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import UsageError
from ..core.layout import read_frames, read_up
from ..core.types import UP_AXES, FrameInfo, LatentMap
from ._npz import map_then_path, metadata_arrays

log = logging.getLogger(__name__)


def frames_from_npz(path: str | Path) -> list[FrameInfo] | None:
    """The frames of a pixel map stored in ``path``, or None: a map ``quash convert``
    wrote (:func:`write_npz_streaming`) or a ``quash query --out RESULT.npz`` file, for
    :func:`~quash_plugins.adapters.masks_per_frame`."""
    with np.load(path, allow_pickle=False) as z:
        return read_frames(z, str(path))


def up_from_npz(path: str | Path) -> str | None:
    """The up axis (``+z``, ``+y``...) of the positions in ``path``, or None when it
    records none (``+z`` is then assumed): a ``quash query --out RESULT.npz`` file (the
    axis ``--up`` gave, else the map's) or a map ``quash convert`` wrote."""
    with np.load(path, allow_pickle=False) as z:
        return read_up(z, str(path))


def _zarr_attrs(path: str | Path) -> dict[str, Any]:
    """The root attributes of the zarr store ``path``."""
    from ..core.errors import MapFormatError
    from ..core.optional import require

    zarr = require("zarr", "dask", "Reading zarr stores")
    try:
        return dict(zarr.open_group(str(path), mode="r").attrs)
    except Exception as exc:  # noqa: BLE001 - zarr raises many types for a bad store
        raise MapFormatError(f"{path}: not a readable zarr store ({exc}).") from None


def frames_from_zarr(path: str | Path) -> list[FrameInfo] | None:
    """The frames of a pixel map stored in the zarr store ``path``, or None: a
    ``quash query --out RESULT.zarr`` store (``LazyQuery.to_zarr``, ``query_to_zarr``:
    attributes ``frame_ids``, ``frame_hw``, ``frame_offsets``, as the NPZ result's
    arrays) or a map ``quash convert`` wrote (its ``frames`` attribute), for
    :func:`~quash_plugins.adapters.masks_per_frame`.

    Examples
    --------
    >>> import zarr  # doctest: +SKIP
    >>> from quash_plugins.adapters import masks_per_frame  # doctest: +SKIP
    >>> store = "chair.zarr"  # quash query saved-feat chair --out chair.zarr  # doctest: +SKIP
    >>> chair = zarr.open_group(store, mode="r")["masks"][0]  # doctest: +SKIP
    >>> per_image = masks_per_frame(frames_from_zarr(store), chair)  # doctest: +SKIP
    """
    attrs = _zarr_attrs(path)
    if attrs.get("frames"):  # a map store: FrameInfo fields (image paths kept)
        return [FrameInfo(**f) for f in attrs["frames"]]
    return read_frames(attrs, str(path), what="attribute")


def up_from_zarr(path: str | Path) -> str | None:
    """The up axis of the positions of the zarr store ``path``, or None when it records
    none (``+z`` is then assumed): a ``quash query --out RESULT.zarr`` store (attribute
    ``up``: the axis ``--up`` gave, else the map's, as the NPZ result's ``up``) or a map
    ``quash convert`` wrote (the ``up`` its ``source`` attribute records)."""
    attrs = _zarr_attrs(path)
    if "up" not in attrs and isinstance(attrs.get("source"), dict):
        attrs = attrs["source"]  # a map store
    return read_up(attrs, str(path), what="attribute")


def write_npz_streaming(lmap: LatentMap, path: str | Path, chunk_rows: int = 65536) -> Path:
    """Write ``lmap`` as a portable NPZ at ``path``, ``chunk_rows`` rows at a time.

    What ``quash convert`` uses for lazy maps (HDF5 datasets, per-frame features, rows
    gathered through an index): the embeddings are never held whole in memory. Values
    and dtype are kept as stored (float16 stays float16, rows are not normalised; the
    ``normalize`` flag is recorded instead). The file appears atomically. For a map held
    in memory, :func:`~quash_plugins.adapters.write_npz_map` does the same in one go.

    Parameters
    ----------
    lmap : LatentMap
        The map to write. It comes first, as for every map writer; the old order,
        ``write_npz_streaming(path, lmap)``, still works for this release with a
        :class:`DeprecationWarning` naming the new one.
    path : str or pathlib.Path
        The ``.npz`` file to write; an existing file is replaced. It may not be the
        map's own source file (through any link).
    chunk_rows : int, default 65536
        Rows of embeddings copied at a time.

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    TypeError
        When no argument is a :class:`~quash_plugins.core.types.LatentMap`, or the
        other is not a path.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from quash_plugins import LatentMap
    >>> from quash_plugins.adapters import read_map, write_npz_streaming
    >>> m = LatentMap(np.eye(4, dtype=np.float16))
    >>> p = write_npz_streaming(m, os.path.join(tempfile.mkdtemp(), "m.npz"), chunk_rows=3)
    >>> str(read_map(p).embeddings.dtype)
    'float16'
    """
    from ..core.atomic import atomic_write, refuse_own_input
    from ..core.progress import progress

    lmap, path = map_then_path("write_npz_streaming", lmap, path)
    refuse_own_input(path, lmap.source)
    emb = lmap.embeddings
    n, d = lmap.n, lmap.dim
    dtype = np.dtype(emb.dtype)
    header = {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": (n, d)}
    with (
        atomic_write(path, suffix=".npz") as tmp,
        zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf,
    ):
        with (
            zf.open("embeddings.npy", "w", force_zip64=True) as fp,
            progress(n, f"writing {Path(path).name}") as advance,
        ):
            np.lib.format.write_array_header_2_0(fp, header)
            for start in range(0, n, chunk_rows):
                block = np.ascontiguousarray(emb[start : min(n, start + chunk_rows)], dtype=dtype)
                fp.write(block.tobytes())
                advance(len(block))
        for key, value in metadata_arrays(lmap).items():
            with zf.open(f"{key}.npy", "w", force_zip64=True) as fp:
                np.lib.format.write_array(fp, np.asarray(value), allow_pickle=False)
    return path


#: Output formats of :func:`convert_map`; ``auto`` picks npz or zarr by the suffix.
FORMATS = ("auto", "npz", "zarr", "openlex3d", "vlmaps")


def convert_map(
    source: Any,
    destination: str | Path,
    adapter: str = "auto",
    compress: bool = False,
    format: str = "auto",
    up: str = "auto",
    **options: Any,
) -> Path:
    """Read ``source`` with ``adapter`` and write it to ``destination``.

    ``format``: ``"npz"`` (our portable map), ``"zarr"`` (a chunked store),
    ``"openlex3d"`` (a folder holding OpenLex3D's ``embeddings.npy``, ``index.npy`` and
    ``point_cloud.pcd``; see :func:`~quash_plugins.adapters._openlex3d.write_openlex3d_map`),
    ``"vlmaps"`` (VLMaps' own HDF5 save layout, ``destination/vlmap_cam/vlmaps_cam.h5df``;
    see :func:`~quash_plugins.adapters._vlmaps_write.write_vlmaps_map`; returns that file)
    or ``"auto"``: npz or zarr by the destination's suffix. The source is never written
    to; ``destination`` may not be the source (through any link) nor lie inside it. An
    existing ``destination`` is replaced (a folder only when it is a zarr store, or a
    previous OpenLex3D export for ``"openlex3d"``).

    ``up``: the source map's up axis (``"+z"``, ``"-z"``, ``"+y"``, ...) for a map whose
    format does not record one (a ConceptFusion cloud in a y-up dataset frame); it is
    recorded in the output (the NPZ's ``up``, a Zarr store's or an OpenLex3D export's
    ``source``) and tells ``"vlmaps"`` how to turn the map y-up. ``"auto"`` (default):
    the axis the map's adapter recorded (``source["up"]``), else ``+z``.

    Examples
    --------
    >>> convert_map("saved-map", "room0.npz")  # doctest: +SKIP
    PosixPath('room0.npz')
    """
    from ..core.atomic import check_not_input, refuse_own_input

    dst = Path(destination).expanduser()
    if format not in FORMATS:
        raise UsageError(f"Unknown output format {format!r}; use one of {', '.join(FORMATS)}.")
    if up != "auto" and up not in UP_AXES:
        raise UsageError(f"Unknown up axis {up!r}; use auto or one of {', '.join(UP_AXES)}.")
    sources = [source] if isinstance(source, (str, Path)) else []
    suffix = dst.suffix.lower()
    if format == "openlex3d":
        from ._openlex3d import write_openlex3d_map

        if suffix in (".npz", ".zarr"):
            raise UsageError(
                f"Destination {dst}: --format openlex3d writes a folder (the scene folder "
                f"of OpenLex3D's predictions), not a {suffix} file."
            )
        check_not_input(dst, sources, what="Destination")
        return write_openlex3d_map(_read(source, adapter, up, options), dst)
    if format == "vlmaps":
        from ._vlmaps_write import vlmaps_outputs, write_vlmaps_map

        if suffix in (".npz", ".zarr", ".h5df", ".h5"):
            raise UsageError(
                f"Destination {dst}: --format vlmaps writes a scene folder (DST/"
                f"vlmap_cam/vlmaps_cam.h5df, VLMaps' own layout), not a {suffix} file."
            )
        check_not_input(dst, sources, what="Destination")
        for out in vlmaps_outputs(dst):
            check_not_input(out, sources, what="Destination")
        return write_vlmaps_map(_read(source, adapter, up, options), dst)
    if format == "auto" and suffix not in (".npz", ".zarr"):
        raise UsageError(
            f"Destination {dst} must end in .npz (portable map) or .zarr (Zarr store), or "
            "pass --format openlex3d to write OpenLex3D's prediction folder."
        )
    if format in ("npz", "zarr") and suffix != f".{format}":
        raise UsageError(f"Destination {dst} must end in .{format} for --format {format}.")
    refuse_own_input(dst, sources, folder=suffix == ".zarr")
    lmap = _read(source, adapter, up, options)
    if suffix == ".zarr":
        from ._zarr_store import write_zarr_map

        return Path(write_zarr_map(lmap, dst))
    if isinstance(lmap.embeddings, np.ndarray) and not lmap.frames:
        from ._npz import write_npz_map

        written = write_npz_map(lmap, dst, compress=compress)
    else:
        if compress:
            log.info("--compress is ignored for streamed maps (written uncompressed)")
        written = write_npz_streaming(lmap, dst)
    return written


def _read(source: Any, adapter: str, up: str, options: dict[str, Any]) -> LatentMap:
    """The map to convert, with ``up`` (unless ``"auto"``) as its up axis: a copy when
    ``source`` is a caller's :class:`LatentMap`, whose own ``source`` is left as it is."""
    import copy

    from ..core.maps import read_map

    lmap = read_map(source, adapter, **options)
    if up == "auto":
        return lmap
    recorded = lmap.source.get("up")
    if recorded is not None and recorded != up:
        log.warning(
            "%s: its format records %s as the up axis; --up %s overrides it",
            lmap.source.get("path", "the map"),
            recorded,
            up,
        )
    if lmap is source:
        lmap = copy.copy(lmap)
    lmap.source = {**lmap.source, "up": up}
    return lmap
