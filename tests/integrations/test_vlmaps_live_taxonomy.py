"""A live VLMap loaded from a file finds the taxonomy beside that file, as the file does.

``quash convert scene.npz vl --format vlmaps`` copies the scene's taxonomy to
``vl/vlmap_cam/vlmaps_cam.taxonomy.yaml``; ``quash query vl`` reads it, but the same map
loaded by VLMaps (``vlmap.load_map("vl")``) and queried through the drop-in had no path,
so a taxonomy config without ``file`` failed with "no taxonomy".
"""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from _vlmaps_writers import CAMERA_FIELDS

from quash_plugins import LatentMap, Quash
from quash_plugins.adapters import write_vlmaps_map
from quash_plugins.core.errors import HeuristicError, MapFormatError
from quash_plugins.integrations.vlmaps import as_latent_map, patch_vlmap, query

D = 9
WORDS = ["chair", "armchair", "sofa", "couch", "table", "desk", "other", "background", "nothing"]
TAXONOMY = {"chair": ["armchair"], "sofa": ["couch"], "table": ["desk"]}


class LoadedVLMap:
    """What VLMaps' ``VLMap.load_map(data_dir)`` leaves on a camera-base map."""

    def __init__(self, data_dir: Path, remember_path: bool = True):
        self.map_config = {"pose_info": {"pose_type": "camera_base"}}
        self.categories = None
        map_save_path = Path(data_dir) / "vlmap_cam" / "vlmaps_cam.h5df"
        if remember_path:
            self.map_save_path = map_save_path
        with h5py.File(map_save_path, "r") as f:
            for name in CAMERA_FIELDS:
                setattr(self, name, f[name][()])


@pytest.fixture
def converted(tmp_path):
    """A voxel map written in VLMaps' camera-base layout with its taxonomy beside it."""
    rng = np.random.default_rng(3)
    cells = np.argwhere(np.ones((6, 5, 2)))
    kind = rng.integers(0, 6, len(cells))  # the six object words
    feat = np.eye(D)[kind] + rng.normal(0, 0.05, (len(cells), D))
    lmap = LatentMap(
        feat.astype(np.float32),
        kind="voxels",
        positions=cells * 0.1,
        grid_index=cells,
        voxel_size=0.1,
    )
    folder = tmp_path / "vl"
    written = Path(write_vlmaps_map(lmap, folder))
    (written.parent / "vlmaps_cam.taxonomy.yaml").write_text(yaml.safe_dump(TAXONOMY))
    table = {w: np.eye(D)[i].tolist() for i, w in enumerate(WORDS)}
    config = {
        "encoder": {"name": "table", "table": table},
        "heuristic": {"name": "taxonomy", "n_antonyms": "all"},  # no file: the map's
        "classifier": "contrast",
        "cache": False,
    }
    return folder, written, config


def test_a_loaded_vlmap_reads_the_taxonomy_beside_its_file(converted):
    folder, written, config = converted
    from_file = Quash.from_config(config).query(str(folder), "chair")
    vlmap = patch_vlmap(LoadedVLMap(folder), config)
    mask = vlmap.index_map("chair")
    live = query(vlmap, "chair")
    assert from_file.n_matched > 0
    np.testing.assert_array_equal(mask, from_file.mask)
    assert set(live.queryset.positives) == set(from_file.queryset.positives)
    assert "armchair" in live.queryset.positives
    assert {"sofa", "couch", "table", "desk"} <= set(live.queryset.negatives)
    source = as_latent_map(vlmap).source
    assert source["path"] == str(written)
    assert source["inputs"] == [str(written), str(written.with_name("vlmaps_cam.taxonomy.yaml"))]
    assert source["live"] == "LoadedVLMap"


def test_without_a_file_the_path_option_names_it(converted):
    folder, written, config = converted
    vlmap = LoadedVLMap(folder, remember_path=False)  # an object that does not remember
    with pytest.raises(HeuristicError, match="no taxonomy") as err:
        query(vlmap, "chair", quash=config)
    # the error says why a live map has none, and the two ways to give its file
    assert "live LoadedVLMap object with no file" in str(err.value)
    assert "vlmap.map_save_path" in str(err.value) and "path option" in str(err.value)
    named = query(vlmap, "chair", quash=config, path=str(written))
    assert "armchair" in named.queryset.positives
    with pytest.raises(HeuristicError, match="no taxonomy"):  # None: no file recorded
        query(LoadedVLMap(folder), "chair", quash=config, path=None)
    missing = folder / "vlmap_cam" / "nothing.h5df"
    with pytest.raises(MapFormatError, match="nothing.h5df"):
        query(vlmap, "chair", quash=config, path=str(missing))
