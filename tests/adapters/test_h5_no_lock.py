"""A map read by a query never blocks the mapping process that saves it again.

HDF5 locks the files it opens by default. A process that then opens the map to write it,
as VLMaps' ``save_3d_map`` does (``h5py.File(path, "w")``), failed with "unable to lock
file" after truncating the map to 0 bytes: a query holding the map between two queries
crashed the mapping process and lost the map. The adapters now close an HDF5 map once
read, and its rows are read by opening the file for each block (``H5Rows``), without the
lock where they can; the writer runs in another process here, as it does for real.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest
from _vlmaps_writers import mobile_map, write_vlmaps_h5df

from quash_plugins import Quash, registry
from quash_plugins.core.errors import MapFormatError
from quash_plugins.encoders import TableEncoder

h5py = pytest.importorskip("h5py")

_SAVE_AGAIN = textwrap.dedent(
    """
    import sys

    import h5py
    import numpy as np

    sys.path.insert(0, sys.argv[2])
    from _vlmaps_writers import mobile_map, write_vlmaps_h5df

    write_vlmaps_h5df(sys.argv[1], mobile_map(n=70, d=8, seed=1))  # h5py.File(path, "w")
    with h5py.File(sys.argv[1], "r") as f:
        print(f["grid_feat"].shape[0])
    """
)


def _save_again(path, tests_dir):
    return subprocess.run(
        [sys.executable, "-c", _SAVE_AGAIN, str(path), str(tests_dir)],
        capture_output=True,
        text=True,
        timeout=120,
    )


def _quash():
    words = ["chair", "other", "background", "nothing"]
    vectors = np.eye(4, 8, dtype=np.float32)
    return Quash(TableEncoder(table=dict(zip(words, vectors.tolist()))), instances=False)


def test_a_held_vlmaps_map_is_saved_again_by_another_process(tmp_path, request):
    tests_dir = request.path.parents[1]
    path = write_vlmaps_h5df(tmp_path / "vlmap" / "vlmaps.h5df", mobile_map(n=50, d=8))
    lmap = registry.create("adapters", "vlmaps").read(path)
    assert lmap.n == 50 and lmap.embeddings[:1].shape == (1, 8)
    saved = _save_again(path, tests_dir)
    assert saved.returncode == 0, saved.stderr  # not "unable to lock file"
    assert saved.stdout.strip() == "70"  # the writer's map, whole
    with pytest.raises(MapFormatError, match="changed on disk"):
        lmap.embeddings[:1]  # the old map's view refuses the new file


@pytest.mark.parametrize("given", ["file", "folder"])
def test_the_pipeline_reads_a_map_saved_again_while_it_held_it(tmp_path, request, given):
    """Between two queries the pipeline holds the map (its map cache); a mapping process
    saves it again; the next query reads the new map, given as its file or its folder."""
    tests_dir = request.path.parents[1]
    path = write_vlmaps_h5df(tmp_path / "vlmap" / "vlmaps.h5df", mobile_map(n=50, d=8))
    source = path if given == "file" else tmp_path
    q = _quash()
    assert q.query(source, "chair").mask.size == 50
    saved = _save_again(path, tests_dir)
    assert saved.returncode == 0, saved.stderr
    assert q.query(source, "chair").mask.size == 70


def test_a_held_conceptfusion_map_is_saved_again_by_another_process(tmp_path):
    adapter = registry.create("adapters", "conceptfusion")
    folder = adapter.write_example(tmp_path)
    lmap = adapter.read(folder)
    held = [p for p in folder.rglob("*.h5")]
    assert held and lmap.n > 0
    code = "import sys, h5py\nwith h5py.File(sys.argv[1], 'w') as f: f['x'] = [1]\n"
    for path in held:
        done = subprocess.run(
            [sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60
        )
        assert done.returncode == 0, done.stderr
    del lmap
