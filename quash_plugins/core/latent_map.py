"""The map side of the core data types: :class:`LatentMap` (one embedding per voxel,
point or pixel), :class:`FrameInfo`, the files a map was read from (``source["inputs"]``)
and :func:`prepare_block`.

Shapes are checked here, at the boundary, so that nothing deeper has to.
:mod:`quash_plugins.core.types` re-exports every public name, so
``from quash_plugins.core.types import LatentMap`` keeps working.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .errors import MapFormatError

MapKind = Literal["voxels", "points", "pixels"]
MAP_KINDS = ("voxels", "points", "pixels")
#: The up axes a map's ``source["up"]`` may record: the axis its positions' up points along.
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
#: What an ``--up`` option takes: ``auto`` (the axis the map records, else ``+z``) or an axis.
UP_CHOICES = ("auto", "+z", "-z", "+y", "-y", "+x", "-x")


@dataclass(frozen=True)
class FrameInfo:
    """Where one image's pixels sit in a pixel map's flat item axis.

    Items ``offset : offset + height * width`` belong to this frame, in row-major order.
    """

    frame_id: str
    height: int
    width: int
    offset: int
    image_path: str | None = None

    @property
    def size(self) -> int:
        return self.height * self.width


def _describe_source(source: dict[str, Any]) -> str:
    path = source.get("path")
    return f" in {path}" if path else ""


#: The key of :attr:`LatentMap.source` that lists, as path strings, every file or folder
#: read for the map: the map's ``path`` first, then the files its adapter read beside
#: it (VLMaps' ``obj2cls_dict.txt``, OpenScene's scene points, a feature folder's RGB
#: images...) and the taxonomy beside it (:func:`taxonomy_path_beside`) when there is
#: one. No writer replaces one of them (:func:`source_inputs`).
SOURCE_INPUTS = "inputs"


def taxonomy_path_beside(map_path: Any) -> Any:
    """The ``MAP.taxonomy.yaml`` path beside a map (a :class:`~pathlib.Path`, whether it
    exists or not): the suffix replaced (``room.npz``, a ``store.zarr`` folder), or, for
    a name without one (a ConceptFusion ``saved-map/``, a folder of per-image features),
    ``.taxonomy.yaml`` added: beside the folder, never inside it.

    The taxonomy heuristics read it (``quash make-scene OUT.npz`` writes
    ``OUT.taxonomy.yaml``), so it counts as one of the map's inputs, which no output
    may replace.

    >>> str(taxonomy_path_beside("scenes/room.npz")), str(taxonomy_path_beside("saved-map"))
    ('scenes/room.taxonomy.yaml', 'saved-map.taxonomy.yaml')
    """
    from pathlib import Path

    p = Path(str(map_path))
    if not p.name or p.name in (".", ".."):
        p = p.resolve()
        if not p.name:
            return None
    if p.suffix:  # room.npz, and a folder with one too (store.zarr -> store.taxonomy.yaml)
        return p.with_name(p.name[: -len(p.suffix)] + ".taxonomy.yaml")
    return p.with_name(p.name + ".taxonomy.yaml")


def _path_strings(values: Any) -> list[str]:
    """The paths among ``values`` (one path, or an iterable of them) as strings."""
    import os

    if isinstance(values, (str, os.PathLike)):
        values = [values]
    elif not isinstance(values, (list, tuple)):
        return []
    return [str(v) for v in values if isinstance(v, (str, os.PathLike)) and str(v)]


def record_inputs(source: dict[str, Any], *paths: Any) -> dict[str, Any]:
    """Set ``source["inputs"]`` (:data:`SOURCE_INPUTS`): the map's ``source["path"]``,
    the inputs already recorded, then ``paths`` (a path each; None and anything else
    that is not a path, such as an in-memory list of label names, is skipped), then the
    taxonomy beside the path when that file exists; each once. Returns ``source``.

    Adapters call it with the files they read besides the map's ``path`` (a folder
    stands for everything in it); :func:`~quash_plugins.core.maps.read_map` calls it
    again for every map it reads, so that a third-party adapter's maps have their path
    and taxonomy recorded too.

    >>> record_inputs({"path": "m/grid.npy"}, "m/obstacles.npy", None, ["chair"])["inputs"]
    ['m/grid.npy', 'm/obstacles.npy']
    """
    found = [*_path_strings(source.get("path")), *_path_strings(source.get(SOURCE_INPUTS))]
    for value in paths:
        if not isinstance(value, (list, tuple)):
            found += _path_strings(value)
    beside = taxonomy_path_beside(source["path"]) if source.get("path") else None
    if beside is not None and beside.is_file():
        found.append(str(beside))
    source[SOURCE_INPUTS] = list(dict.fromkeys(found))
    return source


def source_inputs(source: Any) -> list[str]:
    """Every file or folder a map was read from, by its ``source`` dict: ``path``, the
    paths under :data:`SOURCE_INPUTS`, and the taxonomy beside ``path`` (whether or not
    the adapter recorded it: a caller's own :class:`LatentMap` may name only its path).

    What the Python writers refuse to replace
    (:func:`~quash_plugins.core.atomic.refuse_own_input`). Anything but a dict gives [].

    >>> source_inputs({"path": "m.npz", "inputs": ["m.npz", "labels.txt"]})
    ['m.npz', 'labels.txt', 'm.taxonomy.yaml']
    """
    if not isinstance(source, dict):
        return []
    found = [*_path_strings(source.get("path")), *_path_strings(source.get(SOURCE_INPUTS))]
    beside = taxonomy_path_beside(source["path"]) if source.get("path") else None
    if beside is not None:
        found.append(str(beside))
    return list(dict.fromkeys(found))


@dataclass
class LatentMap:
    """A latent-semantic map: one embedding per voxel, point or pixel.

    Parameters
    ----------
    embeddings
        ``(N, D)`` array-like: numpy array, memmap, h5py dataset or dask array. It is
        never copied whole; the pipeline reads it in row chunks.
    kind
        ``"voxels"``, ``"points"`` or ``"pixels"``.
    positions
        ``(N, 3)`` float32, metres.
    colors
        ``(N, 3)`` uint8.
    labels
        ``(N,)`` int ground truth, indices into ``label_names``; negative means unlabelled.
    label_names
        ``(L,)`` names of the ground-truth labels.
    voxel_size
        Edge length of a voxel in metres (voxel maps).
    grid_index
        ``(N, 3)`` int voxel or cell coordinates, used for voxel connectivity.
    frames
        For pixel maps: one :class:`FrameInfo` per image.
    normalize
        True when rows are not unit norm and must be L2-normalised when read
        (VLMaps, ConceptFusion). Zero rows are unobserved and never match.
    source
        Free-form metadata: ``adapter``, ``path``, ``encoder_hint``... and ``inputs``
        (:data:`SOURCE_INPUTS`): every file or folder read for the map, as path strings
        (the map's ``path``, the files its adapter read beside it, the taxonomy beside
        it). The Python writers refuse to replace any of them, and the taxonomy beside
        ``path`` (:func:`source_inputs`).

    Examples
    --------
    >>> import numpy as np
    >>> m = LatentMap(np.eye(3, dtype=np.float32), kind="points")
    >>> m.n, m.dim
    (3, 3)
    """

    embeddings: Any
    kind: MapKind = "points"
    positions: np.ndarray | None = None
    colors: np.ndarray | None = None
    labels: np.ndarray | None = None
    label_names: list[str] | None = None
    voxel_size: float | None = None
    grid_index: np.ndarray | None = None
    frames: list[FrameInfo] | None = None
    normalize: bool = False
    source: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = _describe_source(self.source)
        shape = getattr(self.embeddings, "shape", None)
        if shape is None:
            self.embeddings = np.asarray(self.embeddings)
            shape = self.embeddings.shape
        if len(shape) != 2:
            raise MapFormatError(
                f"Field 'embeddings'{where} must be 2-D (N, D); got shape {tuple(shape)}."
            )
        n, d = int(shape[0]), int(shape[1])
        if d == 0:  # N = 0 is a valid empty map (nothing fused yet); D = 0 is not
            raise MapFormatError(
                f"Field 'embeddings'{where} has no feature dimension (shape {tuple(shape)})."
            )
        try:
            dtype = np.dtype(self.embeddings.dtype)
        except TypeError:  # a torch tensor: "Cannot interpret 'torch.float32' as a data type"
            raise MapFormatError(
                f"Field 'embeddings'{where} is a {type(self.embeddings).__name__} of "
                f"{self.embeddings.dtype}, not an array numpy reads: give a numpy array, "
                "memmap, h5py dataset or dask array (a torch tensor: "
                "embeddings.detach().cpu().numpy())."
            ) from None
        if dtype.kind in "iu":
            raise MapFormatError(
                f"Field 'embeddings'{where} holds integers ({dtype}); embeddings must be "
                "floating point (float16, float32 or float64). Quantised features must be "
                "de-quantised first (e.g. codes.astype(np.float32) * scale + offset)."
            )
        if dtype.kind != "f":
            raise MapFormatError(
                f"Field 'embeddings'{where} must hold floating-point numbers; got dtype {dtype}."
            )
        if self.kind not in MAP_KINDS:
            raise MapFormatError(f"LatentMap kind must be one of {MAP_KINDS}; got {self.kind!r}.")
        self.positions = self._check_rows("positions", self.positions, n, (3,), np.float32, where)
        if self.positions is not None and not np.isfinite(self.positions).all():
            raise MapFormatError(f"Field 'positions'{where} contains NaN or Inf.")
        self.colors = self._check_colors(self.colors, n, where)
        self.grid_index = self._check_rows("grid_index", self.grid_index, n, (3,), None, where)
        if self.grid_index is not None and self.grid_index.dtype.kind not in "iu":
            gi = self.grid_index
            whole = gi.dtype.kind == "f" and np.isfinite(gi).all() and (gi == np.rint(gi)).all()
            if not whole:  # a float index would be read as cells it does not name
                raise MapFormatError(
                    f"Field 'grid_index'{where} must hold whole cell indices; got "
                    f"{gi.dtype}{' with fractions or NaN' if gi.dtype.kind == 'f' else ''}. "
                    "For cells of positions: np.floor(positions / voxel_size).astype(int)."
                )
            self.grid_index = gi.astype(np.int64)
        if self.voxel_size is not None:
            size = self.voxel_size
            ok = isinstance(size, (int, float, np.integer, np.floating)) and not isinstance(
                size, (bool, np.bool_)
            )
            if not ok or not np.isfinite(size) or size <= 0:
                raise MapFormatError(
                    f"Field 'voxel_size'{where} must be a positive number of metres (or None); "
                    f"got {size!r}."
                )
            self.voxel_size = float(size)
        if self.labels is not None:
            self.labels = self._check_rows("labels", self.labels, n, (), None, where)
            if self.labels.dtype.kind not in "iu":
                raise MapFormatError(
                    f"Field 'labels'{where} must be integers; got dtype {self.labels.dtype}."
                )
            self.labels = self.labels.astype(np.int64, copy=False)
        if self.label_names is not None:
            if isinstance(self.label_names, (str, bytes)) or np.ndim(self.label_names) != 1:
                # a string was iterated: label_names="chair" named the labels c, h, a, i, r
                one = self.label_names
                one = one.item() if isinstance(one, np.ndarray) and one.ndim == 0 else one
                hint = f" For one label: label_names=[{one!r}]." if isinstance(one, str) else ""
                raise MapFormatError(
                    f"Field 'label_names'{where} must be a list of names, one per label "
                    f"(label 0 first); got {self.label_names!r}.{hint}"
                )
            self.label_names = [str(x) for x in self.label_names]
            if self.labels is not None and self.labels.size:
                top = int(self.labels.max())
                if top >= len(self.label_names):
                    raise MapFormatError(
                        f"Field 'labels'{where} refers to label {top}, but 'label_names' has "
                        f"only {len(self.label_names)} entries."
                    )
        if self.frames is not None:
            total = sum(f.size for f in self.frames)
            if total != n:
                raise MapFormatError(
                    f"Frames{where} cover {total} pixels but the map has {n} items."
                )

    @staticmethod
    def _check_rows(name, value, n, tail, dtype, where):
        if value is None:
            return None
        arr = np.asarray(value)
        if dtype is not None:
            arr = arr.astype(dtype, copy=False)
        if arr.shape != (n, *tail):
            expected = "(N,)" if not tail else f"(N, {', '.join(map(str, tail))})"
            raise MapFormatError(
                f"Field {name!r}{where} must have shape {expected} with N = {n} "
                f"(the number of embeddings); got {arr.shape}."
            )
        return arr

    @classmethod
    def _check_colors(cls, value, n, where):
        if value is None:
            return None
        arr = np.asarray(value)
        arr = cls._check_rows("colors", arr, n, (3,), None, where)
        if arr.dtype != np.uint8:
            if arr.dtype.kind == "f":
                if not np.isfinite(arr).all():
                    raise MapFormatError(f"Field 'colors'{where} contains NaN or Inf.")
                scale = 255.0 if arr.size and float(arr.max()) <= 1.0 else 1.0
                arr = np.clip(np.rint(arr * scale), 0, 255).astype(np.uint8)
            else:
                arr = np.clip(arr, 0, 255).astype(np.uint8)
        return arr

    @property
    def n(self) -> int:
        """Number of items N."""
        return int(self.embeddings.shape[0])

    @property
    def dim(self) -> int:
        """Embedding dimension D."""
        return int(self.embeddings.shape[1])

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(self.embeddings.dtype)

    def chunk_rows(self, chunk_bytes: int = 256 * 2**20, extra_per_row: int = 0) -> int:
        """Rows per chunk so that one float32 chunk plus ``extra_per_row`` bytes fits."""
        per_row = 4 * self.dim + max(0, int(extra_per_row))
        return max(1, min(self.n, int(chunk_bytes // per_row)))

    def iter_chunks(self, rows: int) -> Iterator[tuple[int, int, np.ndarray]]:
        """Yield ``(start, stop, block)`` with ``block`` an ``(rows, D)`` float32 array.

        Rows are L2-normalised when :attr:`normalize` is set (zero rows stay zero), into
        a new array whenever the rows read share memory with the map (a float32 array or
        memory map is sliced as a view): the map itself is never written. NaN or Inf
        raises :class:`MapFormatError` naming the first bad row. (The pipeline's own pass,
        ``quash_plugins.engine.classify``, reads the rows as stored and never normalises
        them at all.)
        """
        for start in range(0, self.n, rows):
            stop = min(self.n, start + rows)
            raw = self.embeddings[start:stop]
            block = np.asarray(raw, dtype=np.float32)
            owned = block is not raw and not np.may_share_memory(block, raw)
            yield start, stop, prepare_block(block, start, self.normalize, self.source, owned)

    def label_index(self, name: str) -> int | None:
        """Index of a ground-truth label by name (case-insensitive), or None."""
        if not self.label_names:
            return None
        low = name.strip().lower()
        for i, label in enumerate(self.label_names):
            if label.lower() == low:
                return i
        return None

    def __repr__(self) -> str:
        """One line, as :meth:`describe` gives it, with what else the map carries (numpy's
        summary of every array ran to some thirty lines for a scene); the arrays are the
        fields."""
        extra = [
            name
            for name in ("positions", "colors", "grid_index", "labels")
            if getattr(self, name) is not None
        ]
        if self.label_names is not None:
            extra.append(f"{len(self.label_names)} label names")
        if self.frames:
            extra.append(f"{len(self.frames)} frames")
        if self.voxel_size is not None:
            try:
                extra.append(f"voxel_size={float(self.voxel_size):g}")
            except (TypeError, ValueError):  # repr never raises
                extra.append(f"voxel_size={self.voxel_size!r}")
        if self.normalize:
            extra.append("normalize")
        return f"LatentMap({self.describe()}; {', '.join(extra) or 'embeddings only'})"

    def describe(self) -> str:
        """One line: the kind, where the map was read from, its size and dtype (a live
        object, such as a VLMaps ``VLMap``, is named by its type and adapter)."""
        where = self.source.get("path")
        if where is None:
            live = self.source.get("live")
            where = f"live {live} object ({self.source.get('adapter')})" if live else "<memory>"
        return f"{self.kind} map {where}: {self.n} items x {self.dim} ({self.dtype})"


def prepare_block(
    block: np.ndarray,
    start: int,
    normalize: bool,
    source: dict[str, Any] | None = None,
    owned: bool = False,
) -> np.ndarray:
    """Check a float32 block for NaN/Inf and L2-normalise its rows when asked.

    ``block`` is normalised in place only when the caller says it ``owned`` it (a copy
    it made) and it is writable; otherwise the normalised rows are a new array, so a
    block that is a view of a map (a read-only memory map, a user's array) is never
    written.
    """
    if not np.isfinite(block).all():
        bad = int(np.argwhere(~np.isfinite(block))[0][0]) + start
        where = _describe_source(source or {})
        raise MapFormatError(
            f"Field 'embeddings'{where} contains NaN or Inf (first at row {bad}). "
            "Fix or drop those rows before querying."
        )
    if normalize:
        norms = np.linalg.norm(block, axis=1, keepdims=True)
        inplace = owned and block.flags.writeable
        out = block if inplace else np.zeros(block.shape, dtype=np.float32)
        np.divide(block, norms, out=out, where=norms > 0)
        return out
    return block
