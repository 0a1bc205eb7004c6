"""Integer embeddings are refused by every adapter, with a message naming the file."""

from __future__ import annotations

import numpy as np
import pytest
from _cf_writers import cf_arrays, save_openlex3d, save_pointclouds
from _vlmaps_writers import mobile_map, write_vlmaps_2d, write_vlmaps_h5df

from quash_plugins.adapters import read_map
from quash_plugins.core.errors import MapFormatError
from quash_plugins.core.types import LatentMap

INTS = [np.int16, np.int32, np.uint8]


def _npz(tmp_path, dtype):
    path = tmp_path / "m.npz"
    np.savez(path, embeddings=np.arange(40).reshape(10, 4).astype(dtype))
    return path, "npz"


def _cf(tmp_path, dtype):
    arrays = cf_arrays(n=20, d=6)
    arrays["pc_embeddings"] = (arrays["pc_embeddings"] * 10).astype(dtype)
    return save_pointclouds(tmp_path / "m", **arrays).parent, "conceptfusion"


def _frames(tmp_path, dtype):
    folder = tmp_path / "feat"
    folder.mkdir()
    np.save(folder / "f0.npy", np.ones((4, 5, 8), dtype))
    return folder, "image-features"


def _ol(tmp_path, dtype):
    rng = np.random.default_rng(0)
    table = (rng.normal(size=(3, 4)) * 10).astype(dtype)
    folder = save_openlex3d(
        tmp_path / "p", rng.normal(size=(10, 3)), None, table, rng.integers(0, 3, 10)
    )
    return folder, "openlex3d"


def _vlmaps(tmp_path, dtype):
    arrays = mobile_map()
    arrays["grid_feat"] = (arrays["grid_feat"] * 10).astype(dtype)
    return write_vlmaps_h5df(tmp_path / "vlmaps.h5df", arrays), "vlmaps"


def _vlmaps_2d(tmp_path, dtype):
    folder, data = write_vlmaps_2d(tmp_path / "scene")
    np.save(folder / "grid_lseg_1.npy", (data["grid"] * 10).astype(dtype))
    return folder, "vlmaps-2d"


@pytest.mark.parametrize("dtype", INTS)
@pytest.mark.parametrize("make", [_npz, _cf, _frames, _ol, _vlmaps, _vlmaps_2d])
def test_integer_embeddings_are_refused_by_every_adapter(tmp_path, make, dtype):
    source, adapter = make(tmp_path, dtype)
    with pytest.raises(MapFormatError) as info:
        read_map(source, adapter)
    msg = str(info.value)
    assert "integers" in msg and np.dtype(dtype).name in msg, msg
    assert "float" in msg  # the fix


def test_latent_map_refuses_integer_and_non_numeric_embeddings():
    with pytest.raises(MapFormatError, match="holds integers \\(int16\\)"):
        LatentMap(np.ones((3, 2), np.int16), source={"path": "m.npz"})
    with pytest.raises(MapFormatError, match="floating-point"):
        LatentMap(np.ones((3, 2), bool))
    assert LatentMap(np.ones((3, 2), np.float16)).dtype == np.float16
