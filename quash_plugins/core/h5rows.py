"""The rows of one HDF5 dataset, read by opening the file for each read.

An adapter that kept its HDF5 file open while the map lived held HDF5's file lock: a
mapping process that saves the map again (VLMaps' ``save_3d_map`` opens it with ``"w"``)
then failed with "unable to lock file" after truncating it, and lost the map. Opened
without the lock, it could not be opened again in the same process with the lock (the
user's own ``h5py.File(path, "r")`` failed with "file locking flag values don't match").
:class:`H5Rows` holds no file: each read opens the file read-only, reads, and closes it.
It pickles as its file name and dataset path, so a Dask worker reads it the same way.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from .errors import MapFormatError


def open_h5_read(path: str | os.PathLike) -> Any:
    """``h5py.File(path, "r")``, without HDF5's file lock where it can: a writer in
    another process is never blocked by a read. Where this process holds the file open
    with the lock already (a caller's own ``h5py.File``), it is opened as that one is."""
    import h5py

    try:
        return h5py.File(path, "r", locking=False)
    except OSError as exc:
        if "locking flag" not in str(exc):
            raise
        return h5py.File(path, "r")


def _stamp(filename: str) -> tuple[int, int]:
    st = os.stat(filename)
    return st.st_mtime_ns, st.st_size


class H5Rows:
    """A read-only, row-sliceable view of the HDF5 dataset ``dataset`` of ``filename``.

    ``view[a:b]`` (or any key an ``h5py.Dataset`` takes) opens the file, reads and
    closes it. A file that changed on disk since the view was made (its modification
    time or size) is refused, not read: its rows may no longer be the map's.

    Parameters
    ----------
    filename, dataset
        The file and the dataset's path in it (``"/grid_feat"``).
    shape, dtype, chunks
        The dataset's, recorded when the view is made (``chunks``: its HDF5 chunk shape,
        or None when it is stored contiguously).
    stamp
        The file's ``(st_mtime_ns, st_size)`` when the view was made; None reads it now.
    """

    def __init__(
        self,
        filename: str | os.PathLike,
        dataset: str,
        shape: tuple[int, ...],
        dtype: Any,
        chunks: tuple[int, ...] | None = None,
        stamp: tuple[int, int] | None = None,
    ) -> None:
        self.filename = str(filename)
        self.dataset = str(dataset)
        self.shape = tuple(int(s) for s in shape)
        self.dtype = np.dtype(dtype)
        self.ndim = len(self.shape)
        self.chunks = tuple(int(c) for c in chunks) if chunks else None
        self.stamp = tuple(stamp) if stamp is not None else _stamp(self.filename)

    @classmethod
    def from_dataset(cls, ds: Any) -> H5Rows:
        """The view of an open ``h5py.Dataset`` (its file may be closed afterwards)."""
        filename = ds.file.filename
        return cls(filename, ds.name, ds.shape, ds.dtype, ds.chunks, _stamp(filename))

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"H5Rows({self.filename!r}, {self.dataset!r}, shape={self.shape}, {self.dtype})"

    def __getitem__(self, key: Any) -> np.ndarray:
        try:
            now = _stamp(self.filename)
        except OSError as exc:
            raise MapFormatError(
                f"{self.filename}: cannot read the map's dataset {self.dataset!r} "
                f"({exc.strerror}); it was there when the map was read."
            ) from None
        if now != self.stamp:
            raise MapFormatError(
                f"{self.filename} changed on disk since the map was read (a mapping process "
                "saved it again?): its rows may no longer be the map's. Query it again: a "
                "Quash reads a changed map anew (read_map, or the quash command)."
            )
        with open_h5_read(self.filename) as f:
            return np.asarray(f[self.dataset][key])
