"""Opening a map's HDF5 file for reading, without HDF5's file lock.

HDF5 locks a file it opens, by default, and a process that then opens it to write
(VLMaps' ``save_3d_map`` saves ``vlmaps.h5df`` with mode ``"w"``) fails with "unable to
lock file" *after* truncating it: a query holding the map open between two queries
would make a running mapping process crash and lose the map it was saving. A reader
here never blocks a writer: the maps are opened read-only, without the lock, and the
pipeline's map cache reads a file again once its modification time or size changes.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def open_h5_read(h5py: Any, path: str | Path) -> Any:
    """``h5py.File(path, "r")`` without HDF5's file lock (see the module docstring)."""
    return h5py.File(path, "r", locking=False)
