"""A map read with the wrong adapter: the error names the adapter that reads it.

Before, ``quash query SCENE chair --adapter vlmaps-2d`` on a 3D VLMaps scene said only
"no grid_lseg_1.npy found", and a config with ``adapter: vlmaps`` on a 2023 top-down map
said "not a VLMaps map file", with nothing to say that the other VLMaps adapter reads it.
"""

from __future__ import annotations

import numpy as np
import pytest
from _vlmaps_writers import mobile_map, write_vlmaps_2d, write_vlmaps_h5df

from quash_plugins.adapters import read_map
from quash_plugins.cli.main import main
from quash_plugins.core.errors import MapFormatError


@pytest.fixture
def scenes(tmp_path):
    write_vlmaps_h5df(tmp_path / "s3d/vlmap/vlmaps.h5df", mobile_map(n=20, d=4, gs=20, vh=4))
    write_vlmaps_2d(tmp_path / "s2d", gs=12, d=4)
    np.savez(tmp_path / "m.npz", embeddings=np.eye(4, dtype=np.float32))
    return tmp_path


@pytest.mark.parametrize(
    ("where", "chosen", "right"),
    [
        ("s3d", "vlmaps-2d", "vlmaps"),
        ("s2d", "vlmaps", "vlmaps-2d"),
        ("s3d/vlmap/vlmaps.h5df", "npz", "vlmaps"),
        ("m.npz", "vlmaps", "npz"),
    ],
)
def test_error_names_the_adapter_that_reads_it(scenes, where, chosen, right):
    with pytest.raises(MapFormatError) as err:
        read_map(scenes / where, chosen)
    msg = str(err.value)
    assert f"It looks like a {right!r} map, not a {chosen!r} one" in msg
    assert f"--adapter {right}" in msg
    assert read_map(scenes / where, right).n > 0  # and that adapter does read it


def test_no_suggestion_when_nothing_else_reads_it(scenes):
    bad = scenes / "bad.h5df"
    bad.write_bytes(b"not an hdf5 file at all")
    with pytest.raises(MapFormatError) as err:
        read_map(bad, "vlmaps")
    assert "It looks like" not in str(err.value)


def test_cli_with_the_config_adapter(scenes, capsys):
    cfg = scenes / "c.yaml"
    cfg.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0], other: [0, 1, 0, 0]}}\n"
        "heuristic: none\nclassifier: contrast\ncache: false\nadapter: {name: vlmaps}\n"
    )
    assert main(["query", str(scenes / "s2d"), "chair", "-c", str(cfg)]) == 1
    err = " ".join(capsys.readouterr().err.split())
    assert "not a VLMaps map file" in err and "--adapter vlmaps-2d" in err


def test_a_project_folder_names_the_maps_inside_it(tmp_path):
    """ConceptFusion's output folder holds saved-map/ and saved-feat/: no adapter reads the
    folder itself, and the error names the sub-folders one does, with their adapters."""
    from _cf_writers import cf_arrays, save_feat_pt, save_pointclouds

    save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=6, d=4))
    save_feat_pt(tmp_path / "saved-feat", "frame0", np.ones((2, 3, 4), np.float16))
    (tmp_path / "notes").mkdir()
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path)
    msg = str(info.value)
    assert "No adapter recognises" in msg
    assert f"{tmp_path / 'saved-feat'} (image-features)" in msg
    assert f"{tmp_path / 'saved-map'} (conceptfusion)" in msg and "notes" not in msg


def test_a_folder_of_other_arrays_is_no_feature_folder(tmp_path):
    """A ConceptFusion run folder holds saved-map/ beside arrays that are no frames
    (labels.npy, poses.npy): the image-features adapter does not claim it (its error
    blamed labels.npy for not being a frame), so the error names the map inside."""
    from _cf_writers import cf_arrays, save_pointclouds

    save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=6, d=4))
    np.save(tmp_path / "labels.npy", np.zeros(6, np.int64))
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path)
    msg = str(info.value)
    assert "No adapter recognises" in msg and "labels.npy" not in msg
    assert f"{tmp_path / 'saved-map'} (conceptfusion)" in msg
    np.save(tmp_path / "frame0.npy", np.ones((2, 3, 4), np.float32))  # a frame: claimed
    from quash_plugins.adapters import detect_adapter

    assert detect_adapter(tmp_path) == "image-features"


def test_a_folder_of_map_files_names_them(tmp_path):
    """A folder holding two portable maps (room0.npz, scene.npz) is no map: the error
    names the map files inside it, as it names map folders, so the user can pass one."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    for stem in ("room0", "scene"):
        write_npz_map(LatentMap(np.eye(3, dtype=np.float32)), tmp_path / f"{stem}.npz")
    (tmp_path / "notes.txt").write_text("not a map", encoding="utf-8")
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path)
    msg = str(info.value)
    assert f"{tmp_path / 'room0.npz'} (npz), {tmp_path / 'scene.npz'} (npz)" in msg
    assert "notes" not in msg
