"""Core data types: :class:`LatentMap`, :class:`QuerySet`, :class:`QueryResult`.

Shapes are checked here, at the boundary, so that nothing deeper has to.
"""

from __future__ import annotations

import logging
import math
import unicodedata
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .errors import MapFormatError, QuashError
from .presence_text import presence_words

log = logging.getLogger(__name__)

MapKind = Literal["voxels", "points", "pixels"]
MAP_KINDS = ("voxels", "points", "pixels")
#: The up axes a map's ``source["up"]`` may record: the axis its positions' up points along.
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
#: What an ``--up`` option takes: ``auto`` (the axis the map records, else ``+z``) or an axis.
UP_CHOICES = ("auto", "+z", "-z", "+y", "-y", "+x", "-x")

#: Generic negatives the paper always adds to the antonyms.
DEFAULT_NEGATIVES: tuple[str, ...] = ("other", "background", "nothing")


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
    """The ``MAP.taxonomy.yaml`` path beside a map file (a :class:`~pathlib.Path`,
    whether it exists or not), or None for a path without a suffix.

    The taxonomy heuristics read it (``quash make-scene OUT.npz`` writes
    ``OUT.taxonomy.yaml``), so it counts as one of the map's inputs, which no output
    may replace.

    >>> str(taxonomy_path_beside("scenes/room.npz")), taxonomy_path_beside("saved-map")
    ('scenes/room.taxonomy.yaml', None)
    """
    from pathlib import Path

    p = Path(str(map_path))
    return p.with_name(p.name[: -len(p.suffix)] + ".taxonomy.yaml") if p.suffix else None


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
        dtype = np.dtype(self.embeddings.dtype)
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
        if self.labels is not None:
            self.labels = self._check_rows("labels", self.labels, n, (), None, where)
            if self.labels.dtype.kind not in "iu":
                raise MapFormatError(
                    f"Field 'labels'{where} must be integers; got dtype {self.labels.dtype}."
                )
            self.labels = self.labels.astype(np.int64, copy=False)
        if self.label_names is not None:
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

    def describe(self) -> str:
        where = self.source.get("path", "<memory>")
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


@dataclass
class QuerySet:
    """The expanded query: positives (semantic synonyms) and negatives (antonyms).

    ``provenance`` records how the set was made (heuristic, parameters, seed), so an
    experiment can be reproduced from the YAML alone.
    """

    query: str
    positives: list[str]
    negatives: list[str]
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.query = check_query(self.query)
        self.positives = _dedupe(self.positives)
        self.negatives = [n for n in _dedupe(self.negatives) if n not in set(self.positives)]
        if not self.positives:
            raise QuashError(f"Query set for {self.query!r} has no positives.")

    def with_negatives(self, extra: Sequence[str]) -> QuerySet:
        """A copy with ``extra`` appended to the negatives (positives win on overlap)."""
        return QuerySet(
            self.query, list(self.positives), [*self.negatives, *extra], dict(self.provenance)
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "positives": list(self.positives),
            "negatives": list(self.negatives),
            "provenance": _plain(self.provenance),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> QuerySet:
        return cls(
            data["query"],
            list(data.get("positives", [])),
            list(data.get("negatives", [])),
            dict(data.get("provenance", {})),
        )

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False, allow_unicode=True)


#: Format characters that reorder text on a terminal (bidirectional overrides).
_BIDI = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def is_control(char: str) -> bool:
    """True for a control character (C0, DEL, C1) or a bidirectional override."""
    return unicodedata.category(char) == "Cc" or char in _BIDI


def escape_control(text: str) -> str:
    r"""``text`` with control characters written as escapes, safe to print on a terminal.

    Newlines and tabs are kept; every other control character (escape sequences,
    carriage returns, NUL, bidirectional overrides) is written as ``\xNN``/``\uNNNN``.

    Examples
    --------
    >>> escape_control("chair\x1b[31m")
    'chair\\x1b[31m'
    """

    def bad(c: str) -> bool:
        return c not in "\n\t" and is_control(c)

    if not any(bad(c) for c in text):
        return text
    return "".join(c.encode("unicode_escape").decode("ascii") if bad(c) else c for c in text)


def check_query(text: Any) -> str:
    """Collapse a query's white space; reject empty queries and control characters.

    Tabs and newlines count as spaces. Any other control character (an escape sequence
    that would drive the terminal, a NUL that C code would cut the text at, a
    bidirectional override) is refused with its position, never silently dropped.
    """
    if not isinstance(text, str):
        raise QuashError(f"A query must be a string; got {type(text).__name__}.")
    stripped = " ".join(text.split())
    if not stripped:
        raise QuashError("The query is empty. Pass a word or phrase, e.g. 'chair'.")
    bad = next((i for i, c in enumerate(stripped) if is_control(c)), None)
    if bad is not None:
        code = f"U+{ord(stripped[bad]):04X}"
        raise QuashError(
            f"The query '{escape_control(stripped)}' contains a control character ({code}) at "
            f"position {bad}. Queries are plain text: remove it."
        )
    return stripped


def _dedupe(items: Sequence[str]) -> list[str]:
    """Collapse white space and drop empty, repeated and control-character entries."""
    seen: set[str] = set()
    out = []
    for item in items:
        s = " ".join(str(item).split())
        if s and any(is_control(c) for c in s):
            log.warning("dropping %r from a query set: it holds control characters", s)
            continue
        if s and s not in seen:
            seen.add(s)
            out.append(s)
    return out


def _plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays and tuples into YAML/JSON-friendly values."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return obj


@dataclass
class Instance:
    """A connected group of matched items: what a robot navigates to.

    Attributes
    ----------
    id
        Its rank in :attr:`QueryResult.instances` (0 is the largest).
    indices
        ``(M,)`` int: the map's items (rows) it holds; ``size`` is ``M``.
    centroid
        ``(3,)`` float32: the mean position of its items, in metres in the map's frame
        (a pixel map without positions: pixel ``(col, row, 0)``).
    bbox_min, bbox_max
        ``(3,)`` float32: the corners of its axis-aligned box, in the same units.
    mean_score
        The mean raw score of its items.
    frame_id
        For a pixel map, the image it lies in; None otherwise.
    """

    id: int
    indices: np.ndarray
    centroid: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    mean_score: float
    frame_id: str | None = None

    @property
    def size(self) -> int:
        return int(len(self.indices))

    def __repr__(self) -> str:
        """One line (its size, centroid and mean score), not every index of its items."""
        centroid = ", ".join(f"{float(x):.3g}" for x in np.ravel(self.centroid))
        frame = f", frame_id={self.frame_id!r}" if self.frame_id is not None else ""
        return (
            f"Instance(id={self.id}, size={self.size}, centroid=[{centroid}], "
            f"mean_score={float(self.mean_score):.3f}{frame})"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "size": self.size,
            "centroid": [float(x) for x in self.centroid],
            "bbox_min": [float(x) for x in self.bbox_min],
            "bbox_max": [float(x) for x in self.bbox_max],
            "mean_score": float(self.mean_score),
            "frame_id": self.frame_id,
        }


@dataclass
class QueryResult:
    """The answer to one query over one map.

    Row ``i`` of every ``(N,)`` array is item ``i`` of the map, in the order it was read
    (for a VLMaps map, row ``i`` of ``grid_feat``). To save results as ``quash query
    --out`` does, use :func:`quash_plugins.engine.write_results_npz`.

    Attributes
    ----------
    queryset
        The :class:`QuerySet` the classifier was trained on: the query, its positives
        and negatives, and its ``provenance`` (the heuristic and its parameters, the
        refinement, the presence check's decision).
    mask
        ``(N,)`` bool, True where the item matches.
    scores
        ``(N,)`` float32 raw decision values; ``mask == scores > threshold``.
    display_scores
        ``(N,)`` float32 in [0, 1], for colormaps; 0.5 at the threshold.
    threshold
        The score above which an item matches.
    instances
        The matched items in connected groups (:class:`Instance`), largest first; empty
        when nothing matched or the config groups none (``instances: false``, see
        :attr:`n_instances`).
    timings
        Seconds per stage (``read``, ``expand``, ``encode``, ``fit``, ``classify``, ...)
        and ``total``.
    classifier
        The classifier that decided, in words (with its refinement, if any).
    config_name
        The ``name`` of the config.
    map_source
        The map's record as its adapter read it (``adapter``, ``path``, ``up``...,
        ``inputs``: the files read for it, which ``write_results_npz`` never replaces).
    rejected
        ``(N,)`` bool: the items the last pass matched that the presence check dropped
        (what an absent object's look-alikes were); None when the config has no check.
    query
        The query text (``queryset.query``).
    n_matched
        How many items match.
    n_instances
        ``len(instances)``, or None when the config groups none.
    share
        ``n_matched / N``.
    presence
        The presence check's decision in words.
    """

    queryset: QuerySet
    mask: np.ndarray
    scores: np.ndarray
    display_scores: np.ndarray
    threshold: float = 0.0
    instances: list[Instance] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    classifier: str = ""
    config_name: str = ""
    map_source: dict[str, Any] = field(default_factory=dict)
    rejected: np.ndarray | None = None

    @property
    def query(self) -> str:
        return self.queryset.query

    @property
    def n_matched(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def n_instances(self) -> int | None:
        """How many instances were found; None when the config groups none
        (``instances: false``: the pipeline times the grouping only when it runs)."""
        if self.instances or "instances" in self.timings:
            return len(self.instances)
        return None

    @property
    def share(self) -> float:
        return self.n_matched / max(1, len(self.mask))

    @property
    def presence(self) -> str:
        """The presence check's decision in words: ``present``, ``absent: ...`` (why the
        mask is empty), ``not checked: ...`` or ``off`` (the config has no check)."""
        return presence_words(self.queryset.provenance)

    def __repr__(self) -> str:
        """One line: the query, how many of the map's items matched, the instances and
        the presence decision; the arrays and the query set are the fields."""
        instances = "off" if self.n_instances is None else self.n_instances
        return (
            f"QueryResult(query={self.query!r}, matched={self.n_matched} of {len(self.mask)}, "
            f"instances={instances}, presence={self.presence!r}, config={self.config_name!r})"
        )

    def summary(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "matched": self.n_matched,
            "share": self.share,
            "instances": self.n_instances,  # None when the config groups none, not 0
            "presence": self.presence,
            "timings": dict(self.timings),
        }
