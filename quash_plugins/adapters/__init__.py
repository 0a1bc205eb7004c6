"""Map adapters: read maps as their own code writes them.

Use :func:`read_map` with ``adapter="auto"`` to sniff the format.

Examples
--------
>>> from quash_plugins.adapters import read_map
>>> import numpy as np, tempfile, os
>>> path = os.path.join(tempfile.mkdtemp(), "m.npz")
>>> np.savez(path, embeddings=np.eye(4, dtype=np.float32))
>>> read_map(path).n
4
"""

from __future__ import annotations

from ..core.maps import detect_adapter, read_map
from ..core.optional import lazy_exports

__all__ = [
    "read_map",
    "detect_adapter",
    "masks_per_frame",
    "frames_from_npz",
    "frames_from_zarr",
    "up_from_npz",
    "up_from_zarr",
    "pixel_coordinates",
    "convert_map",
    "write_npz_map",
    "write_npz_streaming",
    "read_zarr_map",
    "write_zarr_map",
    "VLMapsLiveAdapter",
    "write_openlex3d_map",
    "check_openlex3d_exportable",
    "write_pcd",
    "to_vlmaps_grid",
    "vlmaps_outputs",
    "write_vlmaps_map",
]

#: Public helpers, imported on first use (keeps ``import quash_plugins.adapters`` light).
_LAZY = {
    "masks_per_frame": "._frames",
    "frames_from_npz": "._convert",
    "frames_from_zarr": "._convert",
    "up_from_npz": "._convert",
    "up_from_zarr": "._convert",
    "pixel_coordinates": "._frames",
    "convert_map": "._convert",
    "write_npz_map": "._npz",
    "write_npz_streaming": "._convert",
    "read_zarr_map": "._zarr_store",
    "write_zarr_map": "._zarr_store",
    "VLMapsLiveAdapter": "._vlmaps_live",
    "write_openlex3d_map": "._openlex3d",
    "check_openlex3d_exportable": "._openlex3d",
    "write_pcd": "._openlex3d",
    "to_vlmaps_grid": "._vlmaps2d",
    "vlmaps_outputs": "._vlmaps_write",
    "write_vlmaps_map": "._vlmaps_write",
}


__getattr__, __dir__ = lazy_exports(__name__, _LAZY)
