"""Lazy ``(N, D)`` array-likes shared by the adapters.

The pipeline reads embeddings in row blocks (``emb[start:stop]``), so an adapter only has
to hand it something with ``shape``, ``dtype`` and row slicing. These classes provide that
over data that is never gathered into one giant copy:

- :class:`ConcatRows` stacks per-image blocks (``(H*W, D)`` each) along the row axis,
  loading at most a few images at a time.
- :class:`IndexedRows` expands an object table through a point-to-object index
  (``rows[i] = table[index[i]]``, zero where ``index[i] < 0``), as OpenLex3D and
  ConceptGraphs store object-level maps; :class:`MaskedRows` does the same through a
  mask (OpenScene: the ``j``-th True point gets row ``j``).

They return numpy arrays in their stored dtype (float16 stays float16); the pipeline
converts each block to float32 when it uses it. ``np.asarray(x)`` still works (it reads
everything), for small maps and tests.

Each pickles (a Dask task sent to a worker) without the data it reads: ``ConcatRows``
as its per-piece loaders (files reopened by path), the other two with their memory-mapped
arrays as references (file, offset, shape, dtype) that the worker reopens. Only arrays
that live in memory with no file behind them travel with their values.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from ..core.errors import MapFormatError
from ..core.maps import memmap_ref, open_memmap_ref
from ..core.progress import progress

log = logging.getLogger(__name__)

#: A loader returns the ``(n_i, D)`` block of one piece (a view where possible).
Loader = Callable[[], np.ndarray]


class _RowArray:
    """Shared indexing: ``x[i]``, ``x[a:b]``, ``x[int_array]``, ``x[bool_mask]``, ``x[rows, cols]``."""

    shape: tuple[int, int]
    dtype: np.dtype
    ndim = 2

    def __len__(self) -> int:
        return self.shape[0]

    @property
    def nbytes(self) -> int:
        return int(self.shape[0]) * int(self.shape[1]) * np.dtype(self.dtype).itemsize

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = self._rows(0, self.shape[0])
        return out.astype(dtype, copy=False) if dtype is not None else out

    def __getitem__(self, key: Any) -> np.ndarray:
        cols: Any = slice(None)
        if isinstance(key, tuple):
            if len(key) != 2:
                raise IndexError(f"{type(self).__name__} takes at most 2 indices; got {len(key)}.")
            key, cols = key
        n = self.shape[0]
        if isinstance(key, (int, np.integer)):
            i = int(key) + n if int(key) < 0 else int(key)
            if not 0 <= i < n:
                raise IndexError(f"row {key} out of range for {n} rows")
            return self._rows(i, i + 1)[0][cols]
        if isinstance(key, slice):
            start, stop, step = key.indices(n)
            if step == 1:
                return self._rows(start, max(start, stop))[:, cols]
            return self._take(np.arange(start, stop, step))[:, cols]
        idx = np.asarray(key)
        if idx.dtype == bool:
            if idx.shape != (n,):
                raise IndexError(f"boolean index must have shape ({n},); got {idx.shape}")
            idx = np.flatnonzero(idx)
        idx = idx.astype(np.int64, copy=False).ravel()
        idx = np.where(idx < 0, idx + n, idx)
        if idx.size and (idx.min() < 0 or idx.max() >= n):
            raise IndexError(f"row index out of range for {n} rows")
        return self._take(idx)[:, cols]

    def _rows(self, start: int, stop: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _take(self, idx: np.ndarray) -> np.ndarray:
        """Gather arbitrary rows (sorted reads, original order restored)."""
        out = np.empty((len(idx), self.shape[1]), dtype=self.dtype)
        if not len(idx):
            return out
        order = np.argsort(idx, kind="stable")
        sorted_idx = idx[order]
        # Read the covering range in blocks of bounded size.
        pos = 0
        while pos < len(sorted_idx):
            lo = int(sorted_idx[pos])
            hi_limit = lo + 65536
            end = int(np.searchsorted(sorted_idx, hi_limit, side="left"))
            hi = int(sorted_idx[end - 1]) + 1
            block = self._rows(lo, hi)
            out[order[pos:end]] = block[sorted_idx[pos:end] - lo]
            pos = end
        return out


class ConcatRows(_RowArray):
    """Rows of several pieces stacked in order, loaded on demand.

    Parameters
    ----------
    sizes
        Row count of each piece.
    loaders
        One callable per piece returning its ``(size, D)`` block.
    dim, dtype
        Embedding dimension D and the dtype every block is returned in.
    names
        A label per piece (its file), used in error messages.
    locate
        Optional ``locate(piece, local_row) -> str`` describing a row (e.g. a pixel).
    cache
        How many loaded pieces to keep (least recently used are dropped).
    check_finite
        Raise :class:`MapFormatError` naming the piece when a read block has NaN or Inf.
    """

    def __init__(
        self,
        sizes: Sequence[int],
        loaders: Sequence[Loader],
        dim: int,
        dtype: Any,
        names: Sequence[str],
        locate: Callable[[int, int], str] | None = None,
        cache: int = 8,
        check_finite: bool = True,
    ) -> None:
        if not (len(sizes) == len(loaders) == len(names)):
            raise ValueError("sizes, loaders and names must have the same length")
        self.sizes = [int(s) for s in sizes]
        self.offsets = np.concatenate([[0], np.cumsum(self.sizes, dtype=np.int64)])
        self._loaders = list(loaders)
        self.names = list(names)
        self.shape = (int(self.offsets[-1]), int(dim))
        self.dtype = np.dtype(dtype)
        self._locate = locate
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._cache_size = max(1, int(cache))
        self.check_finite = check_finite

    def __getstate__(self) -> dict[str, Any]:
        """Pickled (a Dask task sent to a worker) without the loaded pieces: the worker
        loads the pieces its rows need, and a graph never carries frames' data."""
        state = self.__dict__.copy()
        state["_cache"] = OrderedDict()
        return state

    def piece(self, i: int) -> np.ndarray:
        """The ``(size_i, D)`` block of piece ``i`` (cached)."""
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i]
        block = self._loaders[i]()
        if block.shape != (self.sizes[i], self.shape[1]):
            raise MapFormatError(
                f"{self.names[i]}: expected {self.sizes[i]} rows of {self.shape[1]} values; "
                f"got shape {tuple(block.shape)}. The file changed while being read?"
            )
        self._cache[i] = block
        while len(self._cache) > self._cache_size:
            self._cache.popitem(last=False)
        return block

    def _rows(self, start: int, stop: int) -> np.ndarray:
        parts = []
        first = int(np.searchsorted(self.offsets, start, side="right")) - 1
        i = max(0, first)
        pos = start
        while pos < stop and i < len(self.sizes):
            lo, hi = int(self.offsets[i]), int(self.offsets[i + 1])
            if hi > pos:
                a, b = pos - lo, min(stop, hi) - lo
                part = np.asarray(self.piece(i)[a:b]).astype(self.dtype, copy=False)
                if self.check_finite:
                    self._check(part, i, a)
                parts.append(part)
                pos = lo + b
            i += 1
        if not parts:
            return np.empty((0, self.shape[1]), dtype=self.dtype)
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)

    def _check(self, part: np.ndarray, i: int, a: int) -> None:
        if part.dtype.kind != "f" or np.isfinite(part).all():
            return
        bad = int(np.argwhere(~np.isfinite(part))[0][0]) + a
        where = self._locate(i, bad) if self._locate else f"row {bad}"
        raise MapFormatError(
            f"{self.names[i]}: field 'embeddings' contains NaN or Inf (first at {where}). "
            "Fix or re-extract that feature map."
        )


def _by_reference(array: Any) -> Any:
    """What a row array pickles for ``array``: a memmap reference, else the array."""
    ref = memmap_ref(array)
    return ("memmap", ref) if ref is not None else ("array", array)


def _from_reference(state: tuple[str, Any]) -> Any:
    kind, value = state
    return open_memmap_ref(value) if kind == "memmap" else value


class IndexedRows(_RowArray):
    """``rows[i] = table[index[i]]``; rows with a negative index are zero (unobserved).

    Parameters
    ----------
    table
        ``(M, D)`` array-like (e.g. a memmap), one row per object.
    index
        ``(N,)`` int, values in ``[-1, M)`` (a memmap is kept as it is).

    Pickles (a Dask task sent to a worker) a memory-mapped ``table`` or ``index`` as its
    file, offset, shape and dtype (see :func:`~quash_plugins.core.maps.memmap_ref`): the
    worker reopens the file by path, so the task graph does not grow with the table. An
    in-memory array (one that no file backs) is pickled with its values.
    """

    def __init__(self, table: Any, index: Any) -> None:
        self.table = table
        self.index = index if isinstance(index, np.memmap) else np.asarray(index)
        self.shape = (int(self.index.shape[0]), int(table.shape[1]))
        self.dtype = np.dtype(table.dtype)

    def __getstate__(self) -> dict[str, Any]:
        return {"table": _by_reference(self.table), "index": _by_reference(self.index)}

    def __setstate__(self, state: dict[str, Any]) -> None:
        IndexedRows.__init__(self, _from_reference(state["table"]), _from_reference(state["index"]))

    def _rows(self, start: int, stop: int) -> np.ndarray:
        idx = np.asarray(self.index[start:stop])
        out = np.zeros((len(idx), self.shape[1]), dtype=self.dtype)
        valid = idx >= 0
        if valid.any():
            uniq, inverse = np.unique(idx[valid], return_inverse=True)
            out[valid] = np.asarray(self.table[uniq])[inverse]
        return out


class MaskedRows(IndexedRows):
    """``rows[i]`` is the next row of ``table`` where ``mask[i]``, zero elsewhere.

    OpenScene's layout: row ``j`` of ``feat (M, D)`` belongs to the ``j``-th True entry of
    ``mask_full (N,)``. The same rows as :class:`IndexedRows` with the index
    ``-1 / 0, 1, ..., M - 1`` the mask implies, but read as one contiguous slice of the
    table per block, and without the ``(N,)`` int64 index: :attr:`index` is built only
    when asked for (an OpenLex3D export).

    Pickles a memory-mapped ``table`` or ``mask`` by reference (path, offset, shape,
    dtype), an in-memory mask as bits (N / 8 bytes), an in-memory table with its values.
    """

    #: Rows between the stored counts of True entries (one int64 per block).
    MARK_ROWS = 1 << 16

    def __init__(self, table: Any, mask: Any, marks: np.ndarray | None = None) -> None:
        self.table = table
        self.mask = mask if isinstance(mask, np.memmap) else np.asarray(mask, dtype=bool)
        if self.mask.dtype != bool or self.mask.ndim != 1:
            raise ValueError(f"mask must be (N,) bool; got {self.mask.shape} {self.mask.dtype}")
        n = int(self.mask.shape[0])
        self.shape = (n, int(table.shape[1]))
        self.dtype = np.dtype(table.dtype)
        if marks is None:
            b = self.MARK_ROWS
            counts = [int(np.count_nonzero(self.mask[a : a + b])) for a in range(0, n, b)]
            marks = np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64)
        self._marks = marks
        if int(self._marks[-1]) != int(table.shape[0]):
            raise ValueError(
                f"mask marks {int(self._marks[-1])} rows but the table has {table.shape[0]}"
            )

    @property
    def index(self) -> np.ndarray:  # type: ignore[override]
        """``(N,)`` int64: the table row of each item, -1 where the mask is False."""
        mask = np.asarray(self.mask)
        out = np.full(len(mask), -1, dtype=np.int64)
        out[mask] = np.arange(int(self._marks[-1]), dtype=np.int64)
        return out

    def __getstate__(self) -> dict[str, Any]:
        ref = memmap_ref(self.mask)
        if ref is not None:
            mask: tuple[str, Any] = ("memmap", ref)
        else:
            mask = ("bits", (np.packbits(self.mask), int(self.mask.shape[0])))
        return {"table": _by_reference(self.table), "mask": mask, "marks": self._marks}

    def __setstate__(self, state: dict[str, Any]) -> None:
        kind, value = state["mask"]
        if kind == "bits":
            bits, n = value
            mask = np.unpackbits(bits, count=n).astype(bool)
        else:
            mask = _from_reference(state["mask"])
        MaskedRows.__init__(self, _from_reference(state["table"]), mask, state["marks"])

    def _rank(self, start: int) -> int:
        """True entries of the mask before item ``start``."""
        b = start // self.MARK_ROWS
        a = b * self.MARK_ROWS
        return int(self._marks[b]) + int(np.count_nonzero(self.mask[a:start]))

    def _rows(self, start: int, stop: int) -> np.ndarray:
        m = np.asarray(self.mask[start:stop], dtype=bool)
        out = np.zeros((len(m), self.shape[1]), dtype=self.dtype)
        k = int(np.count_nonzero(m))
        if k:
            r0 = self._rank(start)
            out[m] = np.asarray(self.table[r0 : r0 + k])
        return out


def scan_finite(
    arr: Any,
    label: str,
    field: str,
    chunk_rows: int = 65536,
    *,
    fix: str = "Fix or drop those rows before querying.",
    name_read_errors: bool = False,
) -> None:
    """Read ``arr`` in row chunks; raise :class:`MapFormatError` at the first NaN or Inf.

    ``label`` names the file (and dataset) in the message, ``field`` the map field, and
    ``fix`` ends it. ``name_read_errors``: a block that cannot be read (a truncated HDF5
    file) is a :class:`MapFormatError` naming the field and rows too; else the reader's
    own error goes up (``read_map`` names the file).
    """
    n = int(arr.shape[0])
    with progress(n, f"checking {field} for NaN/Inf") as advance:
        for start in range(0, n, chunk_rows):
            stop = min(n, start + chunk_rows)
            try:
                block = np.asarray(arr[start:stop])
            except (OSError, ValueError, RuntimeError) as exc:
                if not name_read_errors:
                    raise
                raise MapFormatError(
                    f"{label}: cannot read field {field!r} rows {start}..{stop} ({exc}). The "
                    "file may be truncated or corrupt."
                ) from None
            if block.dtype.kind == "f" and not np.isfinite(block).all():
                bad = int(np.argwhere(~np.isfinite(block))[0][0]) + start
                raise MapFormatError(
                    f"{label}: field {field!r} contains NaN or Inf (first at row {bad}). {fix}"
                )
            advance(stop - start)


def should_scan(check_finite: bool | str | None, nbytes: int, limit_mb: float) -> bool:
    """Resolve the ``check_finite`` option: True, False, or "auto" (scan up to ``limit_mb``)."""
    try:
        limit = float(limit_mb)
    except (TypeError, ValueError):  # a typo in -o finite_check_mb=..., not a damaged file
        raise MapFormatError(
            f"finite_check_mb must be a number of MiB (e.g. -o finite_check_mb=512); got "
            f"{limit_mb!r}."
        ) from None
    if check_finite in (None, "auto"):
        return nbytes <= limit * 2**20
    if isinstance(check_finite, str):
        raise MapFormatError(f"check_finite must be true, false or 'auto'; got {check_finite!r}.")
    return bool(check_finite)


def colors_to_uint8(values: Any, label: str, color_range: str = "0-255") -> np.ndarray:
    """Convert ``(N, 3)`` colours in ``color_range`` ("0-255", "0-1" or "auto") to uint8."""
    arr = np.asarray(values)
    if arr.dtype == np.uint8:
        return arr
    if arr.dtype.kind not in "fiu":  # text, bool, complex: no colour, not a damaged file
        raise MapFormatError(
            f"{label}: field 'colors' must hold numbers (0-255 or 0-1); got {arr.dtype}. "
            "Re-save the colours as numbers, or leave them out."
        )
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise MapFormatError(f"{label}: field 'colors' contains NaN or Inf.")
    arr = arr.astype(np.float32, copy=False)
    if color_range not in ("0-255", "0-1", "auto"):
        raise MapFormatError(f"color_range must be '0-255', '0-1' or 'auto'; got {color_range!r}.")
    top = float(arr.max()) if arr.size else 0.0
    if color_range == "auto":
        color_range = "0-1" if top <= 1.0 else "0-255"
    elif color_range == "0-1" and top > 1.5:  # a little overshoot is rounding; 255 is not
        raise MapFormatError(
            f"{label}: field 'colors' goes up to {top:.4g}, so it is not in the color_range "
            "'0-1' it is read with (every colour would be white). Read it with color_range "
            "'0-255' or 'auto' (-o color_range=auto)."
        )
    elif color_range == "0-255" and 0.0 < top <= 1.0:
        log.warning(
            "%s: every colour lies in [0, 1] but is read as 0-255, so the map shows black; "
            "if they are 0-1 colours, pass color_range '0-1' or 'auto' (-o color_range=auto)",
            label,
        )
    if color_range == "0-1":
        arr = arr * 255.0
    return np.clip(np.rint(arr), 0, 255).astype(np.uint8)
