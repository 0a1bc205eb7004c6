"""Tensors of a ``torch.save`` file as numpy memory maps of the file itself.

``torch.save`` writes a zip archive: ``<archive>/data.pkl`` (a small pickle that names,
for each tensor, a storage record, its offset, size and strides) and one uncompressed
record ``<archive>/data/<key>`` per storage, the raw little-endian values. A contiguous
tensor is therefore a plain C-ordered array at a fixed byte offset of the ``.pt`` file,
and :func:`tensor_memmaps` opens it as :class:`numpy.memmap`: a reader that pickles as
``(path, offset, shape, dtype)`` (a Dask task reopens it by path on the worker) instead
of the values.

The pickle is read by a restricted unpickler that builds nothing but stand-ins (the
tensor rebuild function, the storage types and ``OrderedDict`` are the only globals it
resolves; anything else stops it): the file's values are never unpickled here, and the
file is still loaded and checked by ``torch.load(weights_only=True)`` as before. A
legacy (non-zip) file, a compressed record, a big-endian file, a dtype numpy lacks
(bfloat16) or a non-contiguous tensor gives no memory map for that tensor; the caller
keeps the tensor as loaded.
"""

from __future__ import annotations

import io
import logging
import pickle
import struct
import zipfile
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

#: torch's legacy storage types (as ``torch.save`` names them) that numpy can map.
STORAGE_DTYPES = {
    "HalfStorage": np.float16,
    "FloatStorage": np.float32,
    "DoubleStorage": np.float64,
    "BoolStorage": np.bool_,
    "ByteStorage": np.uint8,
    "CharStorage": np.int8,
    "ShortStorage": np.int16,
    "IntStorage": np.int32,
    "LongStorage": np.int64,
}
_LOCAL_HEADER = struct.Struct("<IHHHHHIIIHH")  # a zip entry's local file header
_LOCAL_MAGIC = 0x04034B50


class _Unsupported(Exception):
    """The pickle holds something other than tensors in plain containers."""


class _Storage:
    def __init__(self, key: str, dtype: Any) -> None:
        self.key, self.dtype = str(key), dtype


class _Tensor:
    def __init__(self, storage: Any, offset: int, size: tuple, stride: tuple) -> None:
        self.storage, self.offset = storage, int(offset)
        self.size, self.stride = tuple(int(s) for s in size), tuple(int(s) for s in stride)


def _rebuild(storage, storage_offset, size, stride, *_rest) -> _Tensor:
    return _Tensor(storage, storage_offset, size, stride)


class _MetaUnpickler(pickle.Unpickler):
    """Reads ``data.pkl`` into :class:`_Tensor` stand-ins; resolves no other global."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild
        if module == "torch" and name in STORAGE_DTYPES:
            return STORAGE_DTYPES[name]
        if module == "torch" and name.endswith("Storage"):
            return None  # a storage numpy cannot map (bfloat16, complex...): no memmap
        if (module, name) == ("collections", "OrderedDict"):
            return OrderedDict
        raise _Unsupported(f"{module}.{name}")

    def persistent_load(self, pid: Any) -> _Storage:
        if not (isinstance(pid, tuple) and len(pid) == 5 and pid[0] == "storage"):
            raise _Unsupported(f"persistent id {pid!r}")
        return _Storage(pid[2], pid[1])


def _data_start(path: Path, info: zipfile.ZipInfo) -> int:
    """Byte offset of an uncompressed zip member's data in the file."""
    with open(path, "rb") as fh:
        fh.seek(info.header_offset)
        header = fh.read(_LOCAL_HEADER.size)
    fields = _LOCAL_HEADER.unpack(header)
    if fields[0] != _LOCAL_MAGIC:
        raise _Unsupported("bad local header")
    name_len, extra_len = fields[9], fields[10]
    return info.header_offset + _LOCAL_HEADER.size + name_len + extra_len


def _contiguous(size: tuple[int, ...], stride: tuple[int, ...]) -> bool:
    expected = 1
    for n, s in zip(reversed(size), reversed(stride)):
        if n != 1 and s != expected:
            return False
        expected *= n
    return True


def tensor_memmaps(path: str | Path) -> dict[str, np.memmap]:
    """``{key: np.memmap}`` for the top-level tensors of a ``torch.save`` dict (or of a
    bare tensor, under the key ``""``) that can be mapped; ``{}`` when none can.

    Each map is read-only, C-ordered, of the tensor's shape and dtype, and reads the
    very bytes ``torch.load`` reads. Tensors with no elements are left out (an empty
    map cannot be memory-mapped).
    """
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as zf:
            pkls = [i for i in zf.infolist() if i.filename.endswith("/data.pkl")]
            if len(pkls) != 1 or pkls[0].file_size > 1 << 20:
                return {}
            prefix = pkls[0].filename[: -len("data.pkl")]
            names = set(zf.namelist())
            order = prefix + "byteorder"
            if order in names and zf.read(order).strip() != b"little":
                return {}
            obj = _MetaUnpickler(io.BytesIO(zf.read(pkls[0]))).load()
            top = {"": obj} if isinstance(obj, _Tensor) else obj
            if not isinstance(top, dict):
                return {}
            out: dict[str, np.memmap] = {}
            for key, t in top.items():
                mm = _memmap(path, zf, prefix, t) if isinstance(t, _Tensor) else None
                if mm is not None:
                    out[str(key)] = mm
            return out
    except Exception as exc:  # noqa: BLE001 - anything odd: keep the tensors as loaded
        log.debug("%s: tensors not memory-mapped (%s: %s)", path, type(exc).__name__, exc)
        return {}


def _memmap(path: Path, zf: zipfile.ZipFile, prefix: str, t: _Tensor) -> np.memmap | None:
    storage = t.storage
    if not isinstance(storage, _Storage) or storage.dtype is None:
        return None
    if not _contiguous(t.size, t.stride) or int(np.prod(t.size, dtype=np.int64)) == 0:
        return None
    try:
        info = zf.getinfo(f"{prefix}data/{storage.key}")
    except KeyError:
        return None
    if info.compress_type != zipfile.ZIP_STORED or info.flag_bits & 0x1:
        return None
    dtype = np.dtype(storage.dtype)
    count = int(np.prod(t.size, dtype=np.int64))
    if (t.offset + count) * dtype.itemsize > info.file_size or t.offset < 0:
        return None
    start = _data_start(path, info) + t.offset * dtype.itemsize
    return np.memmap(path, dtype=dtype, mode="r", offset=start, shape=t.size)
