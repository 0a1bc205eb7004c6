"""``npz``: quash-plugins' portable map format.

Arrays: ``embeddings (N, D)`` (required), ``positions (N, 3)`` metres, ``colors (N, 3)``
uint8, ``labels (N,)`` int, ``label_names (L,)`` str, ``voxel_size`` scalar,
``grid_index (N, 3)`` int, ``kind`` str, ``up`` str (the up axis of the positions,
``source["up"]``: ``"+y"`` for a VLMaps camera-base map), and for pixel maps
``frame_ids (F,)`` str, ``frame_hw (F, 2)`` and ``frame_offsets (F,)`` int. Never unpickled.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ..core.encoder_record import recorded_params
from ..core.errors import MapFormatError
from ..core.interfaces import MapAdapter
from ..core.layout import layout_arrays, map_layout, read_frames, read_up
from ..core.types import LatentMap, record_inputs

log = logging.getLogger(__name__)

OPTIONAL = (
    "positions",
    "colors",
    "labels",
    "label_names",
    "voxel_size",
    "grid_index",
    "kind",
    "normalize",
    "frame_ids",
    "frame_hw",
    "frame_offsets",
    "encoder",
    "encoder_fingerprint",
    "encoder_params",
    "up",
)

#: ``LatentMap.source`` keys stored as 0-d string arrays: the encoder that built the map,
#: as a config names it (``encoder``), its :meth:`fingerprint` and, optionally, the
#: parameters it was built with (``encoder_params``: a JSON object, see
#: :func:`encoder_params`).
ENCODER_KEYS = ("encoder", "encoder_fingerprint", "encoder_params")


def encoder_record(fields: dict[str, Any]) -> dict[str, str]:
    """The encoder record (:data:`ENCODER_KEYS`) among ``fields`` (an HDF5 file's
    attributes, an export's JSON), as strings; other fields are ignored, and so (with a
    debug log) is an ``encoder_params`` that is not a JSON object: it is advisory."""
    out: dict[str, str] = {}
    for key in ENCODER_KEYS:
        value = fields.get(key)
        if isinstance(value, bytes):
            value = value.decode("utf-8", "replace")
        if isinstance(value, np.ndarray) and value.shape == ():
            value = str(value)
        if isinstance(value, str) and value:
            out[key] = value
    return _valid_params(out)


def _valid_params(record: dict[str, str], where: Any = None) -> dict[str, str]:
    """``record`` less an ``encoder_params`` that :func:`recorded_params` cannot read."""
    if "encoder_params" in record and recorded_params(record, where) is None:
        record.pop("encoder_params")
    return record


def check_declared_sizes(path: Path) -> None:
    """Refuse an NPZ whose arrays declare more data than the file holds.

    A damaged or hostile header can declare ``(10**11, 16)`` rows; loading it would try
    to allocate terabytes. Each ``.npy`` member's header is read and its declared size
    compared with the member's stored size before anything is allocated.
    """
    fmt = np.lib.format
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            name = info.filename[: -len(".npy")]
            try:
                with zf.open(info) as f:
                    version = fmt.read_magic(f)
                    read = (
                        fmt.read_array_header_1_0
                        if version == (1, 0)
                        else fmt.read_array_header_2_0
                    )
                    shape, _, dtype = read(f)
                    header = f.tell()
            except (ValueError, OSError, EOFError, zipfile.BadZipFile) as exc:
                raise MapFormatError(
                    f"{path}: array {name!r} has a damaged header ({exc}). Copy or convert "
                    "the map again."
                ) from None
            if dtype.hasobject:
                continue  # refused when loaded: pickles are never read
            declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
            stored = info.file_size - header
            if declared > stored:
                raise MapFormatError(
                    f"{path}: array {name!r} declares shape {tuple(shape)} {dtype} "
                    f"({_size(declared)}), but the file holds only {_size(max(0, stored))} of "
                    "it: the file is truncated or damaged. Copy or convert the map again."
                )


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if n < 1024 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} TiB"


def result_hint(names: Any, made_from: Any = None) -> str:
    """A sentence for a map read that found no embeddings but a query's result (``masks``
    and ``scores``: what ``quash query --out`` writes), naming the map it was made from
    when its record says; "" for anything else."""
    if not {"masks", "scores"} <= set(names):
        return ""
    source = made_from.get("path") if isinstance(made_from, dict) else None
    return (
        " It is a query result (quash query --out: masks and scores, no embeddings), not "
        "a map: query the map it was made from"
        + (f", {source}." if source else " (its provenance names it).")
    )


class NpzAdapter(MapAdapter):
    """Read quash-plugins' portable NPZ map (see :func:`write_npz_map`)."""

    name = "npz"
    priority = 10
    suffixes = (".npz",)

    def sniff(self, source: Any) -> bool:
        if not isinstance(source, (str, Path)):
            return False
        p = Path(source)
        if not p.is_file() or not zipfile.is_zipfile(p):
            return False
        try:
            with zipfile.ZipFile(p) as z:
                return "embeddings.npy" in z.namelist()
        except (OSError, zipfile.BadZipFile):
            return False

    def read(self, source: Any, **options: Any) -> LatentMap:
        self.options(options)  # it takes none: a misspelt option is an error, not ignored
        path = Path(source)
        if not path.exists():
            raise MapFormatError(f"Map not found: {path}")
        try:
            z = np.load(path, allow_pickle=False)
        except ValueError as exc:
            raise MapFormatError(
                f"{path}: holds pickled objects, which are never loaded. Store strings as "
                f"fixed-width unicode arrays ({exc})."
            ) from None
        except (OSError, zipfile.BadZipFile, EOFError) as exc:
            raise MapFormatError(f"{path}: not a readable NPZ file ({exc}).") from None
        with z:
            if "embeddings" not in z.files:
                made_from = None
                if "provenance" in z.files:
                    with contextlib.suppress(ValueError, TypeError, AttributeError):
                        made_from = json.loads(str(z["provenance"])).get("map")
                raise MapFormatError(
                    f"{path}: missing array 'embeddings' (N, D). Found: {', '.join(z.files)}."
                    + result_hint(z.files, made_from)
                )
            check_declared_sizes(path)
            try:
                data = {k: z[k] for k in ("embeddings", *OPTIONAL) if k in z.files}
            except ValueError as exc:
                raise MapFormatError(f"{path}: an array holds pickled objects ({exc}).") from None
        built_by = _valid_params({k: str(data.pop(k)) for k in ENCODER_KEYS if k in data}, path)
        up = read_up(data, str(path))
        if up is not None:
            built_by["up"] = up
        frames = read_frames(data, str(path))
        kind = str(data.pop("kind")) if "kind" in data else None
        voxel = float(data.pop("voxel_size")) if "voxel_size" in data else None
        normalize = bool(data.pop("normalize")) if "normalize" in data else False
        names = data.pop("label_names", None)
        if kind is None:
            kind = "voxels" if voxel else "points"
        return LatentMap(
            embeddings=data["embeddings"],
            kind=kind,
            positions=data.get("positions"),
            colors=data.get("colors"),
            labels=data.get("labels"),
            label_names=[str(n) for n in names] if names is not None else None,
            voxel_size=voxel,
            grid_index=data.get("grid_index"),
            normalize=normalize,
            frames=frames,
            source=record_inputs({"adapter": self.name, "path": str(path), **built_by}),
        )

    def write_example(self, directory: Path) -> Path:
        rng = np.random.default_rng(0)
        lmap = LatentMap(
            rng.normal(size=(40, 8)).astype(np.float32),
            positions=rng.uniform(0, 2, size=(40, 3)).astype(np.float32),
            colors=rng.integers(0, 255, size=(40, 3), dtype=np.uint8),
            labels=rng.integers(0, 3, size=40),
            label_names=["floor", "chair", "table"],
        )
        return write_npz_map(lmap, Path(directory) / "example.npz")


def metadata_arrays(lmap: LatentMap) -> dict[str, Any]:
    """Every NPZ array of ``lmap`` except ``embeddings`` (kind, positions, ..., frames)."""
    arrays: dict[str, Any] = {"kind": np.asarray(lmap.kind)}
    for key in ("positions", "colors", "labels", "grid_index"):
        value = getattr(lmap, key)
        if value is not None:
            arrays[key] = np.asarray(value)
    if lmap.label_names is not None:
        arrays["label_names"] = np.asarray(lmap.label_names, dtype=str)
    if lmap.voxel_size is not None:
        arrays["voxel_size"] = np.float32(lmap.voxel_size)
    if lmap.normalize:
        arrays["normalize"] = np.asarray(True)
    for key in ENCODER_KEYS:
        if isinstance(lmap.source.get(key), str):
            arrays[key] = np.asarray(lmap.source[key], dtype=str)
    arrays.update(layout_arrays(map_layout(lmap)))  # up axis and frames (core.layout)
    return arrays


def map_then_path(writer: str, lmap: Any, path: Any) -> tuple[LatentMap, Path]:
    """``(lmap, Path(path))`` for ``writer(lmap, path, ...)``, the order of every map writer.

    The old order of the NPZ writers, ``writer(path, lmap)``, is still accepted for one
    release: the two are swapped and a :class:`DeprecationWarning` names the new order
    (attributed to the writer's caller). Anything else is a :class:`TypeError`.
    """
    if not isinstance(lmap, LatentMap) and isinstance(path, LatentMap):
        warnings.warn(
            f"{writer}(path, lmap) is deprecated: pass the map first, {writer}(lmap, path), "
            "as write_zarr_map, write_vlmaps_map and write_openlex3d_map take it. The old "
            "order will be refused in the next release.",
            DeprecationWarning,
            stacklevel=3,  # this helper's caller is the writer; the warning names its caller
        )
        lmap, path = path, lmap
    if not isinstance(lmap, LatentMap):
        raise TypeError(
            f"{writer}(lmap, path): the first argument must be a LatentMap (got "
            f"{type(lmap).__name__}) and the second the output path. Read a map with "
            "quash_plugins.adapters.read_map, or build one with LatentMap(embeddings, ...)."
        )
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(
            f"{writer}(lmap, path): the second argument must be the output path, a str or "
            f"pathlib.Path (got {type(path).__name__})."
        )
    return lmap, Path(path)


def write_npz_map(lmap: LatentMap, path: str | Path, compress: bool = False) -> Path:
    """Write ``lmap`` as a portable NPZ at ``path`` atomically; returns ``path``.

    The map comes first, as for every map writer (``write_zarr_map``,
    ``write_vlmaps_map``, ``write_openlex3d_map``). The old order, ``write_npz_map(path,
    lmap)``, still works for this release with a :class:`DeprecationWarning`.
    Embeddings are read whole here; use
    :func:`quash_plugins.adapters.write_npz_streaming` for lazy maps.
    ``compress``: zip-deflate the arrays (smaller, slower to read).

    ``path`` may not be the map's own source file (through any link).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from quash_plugins.adapters import read_map
    >>> m = LatentMap(np.eye(4, dtype=np.float32), labels=np.arange(4))
    >>> p = write_npz_map(m, os.path.join(tempfile.mkdtemp(), "m.npz"))
    >>> read_map(p).labels.tolist()
    [0, 1, 2, 3]
    """
    from ..core.atomic import atomic_write, refuse_own_input

    lmap, path = map_then_path("write_npz_map", lmap, path)
    refuse_own_input(path, lmap.source)
    arrays = {"embeddings": np.asarray(lmap.embeddings), **metadata_arrays(lmap)}
    with atomic_write(path, suffix=".npz") as tmp:
        (np.savez_compressed if compress else np.savez)(tmp, **arrays)
    return path
