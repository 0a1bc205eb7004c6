"""``quash convert SRC DST.npz``: any readable map to the portable format."""

from __future__ import annotations

import gzip
import logging
import pickle
import sys

import numpy as np
import pytest
from _cf_writers import cf_arrays, save_feat_pt, save_openlex3d, save_pointclouds, tree_hash

from quash_plugins.adapters import read_map
from quash_plugins.adapters._convert import convert_map, frames_from_npz
from quash_plugins.cli.main import main


def test_convert_conceptfusion_streams_float16(tmp_path):
    arrays = cf_arrays(n=50, d=8)
    save_pointclouds(tmp_path / "saved-map", **arrays)
    before = tree_hash(tmp_path / "saved-map")
    out = tmp_path / "room.npz"
    assert main(["-q", "convert", str(tmp_path / "saved-map"), str(out)]) == 0
    assert tree_hash(tmp_path / "saved-map") == before
    with np.load(out, allow_pickle=False) as z:
        assert z["embeddings"].dtype == np.float16
        np.testing.assert_array_equal(z["embeddings"], arrays["pc_embeddings"])
        np.testing.assert_array_equal(z["positions"], arrays["pc_points"])
        np.testing.assert_array_equal(z["colors"], np.rint(arrays["pc_colors"]).astype(np.uint8))
        assert bool(z["normalize"]) and str(z["kind"]) == "points"
    back = read_map(out)
    assert back.source["adapter"] == "npz" and back.normalize and back.n == 50


def test_convert_image_features_keeps_frames(tmp_path):
    save_feat_pt(tmp_path / "feat", "a", np.ones((2, 3, 4), np.float16))
    save_feat_pt(tmp_path / "feat", "b", np.full((1, 4, 3, 2), 2.0, np.float32))
    out = tmp_path / "f.npz"
    assert (
        main(["-q", "convert", str(tmp_path / "feat"), str(out), "--adapter", "image-features"])
        == 0
    )
    frames = frames_from_npz(out)
    assert [(f.frame_id, f.height, f.width, f.offset) for f in frames] == [
        ("a", 2, 3, 0),
        ("b", 3, 2, 6),
    ]
    lmap = read_map(out)
    assert lmap.n == 12 and lmap.kind == "pixels"
    np.testing.assert_array_equal(np.asarray(lmap.embeddings)[6:], np.full((6, 4), 2.0))


def test_convert_openlex3d_in_memory_path(tmp_path):
    rng = np.random.default_rng(0)
    table = rng.normal(size=(9, 5)).astype(np.float32)
    save_openlex3d(tmp_path / "p", rng.normal(size=(9, 3)), None, table, np.arange(9))
    out = convert_map(tmp_path / "p", tmp_path / "p.npz")
    with np.load(out) as z:
        np.testing.assert_array_equal(z["embeddings"], table)


def test_convert_pickle_needs_flag(tmp_path, capsys):
    src = tmp_path / "cg.pkl.gz"
    with gzip.open(src, "wb") as f:
        pickle.dump({"objects": [{"clip_ft": np.ones(3), "pcd_np": np.zeros((4, 3))}]}, f)
    out = tmp_path / "cg.npz"
    assert main(["convert", str(src), str(out)]) == 1
    err = capsys.readouterr().err
    assert "cg.pkl.gz" in err and "allow_pickle" in err and not out.exists()
    assert main(["-q", "convert", str(src), str(out), "--allow-pickle"]) == 0
    assert read_map(out).n == 4


def test_convert_refuses_to_write_into_input_or_bad_suffix(tmp_path, capsys):
    save_pointclouds(tmp_path / "m", **cf_arrays(n=5, d=3))
    before = tree_hash(tmp_path / "m")
    assert main(["convert", str(tmp_path / "m"), str(tmp_path / "m" / "x.npz")]) == 2
    assert main(["convert", str(tmp_path / "m"), str(tmp_path / "x.h5")]) == 2
    assert main(["convert", str(tmp_path / "missing"), str(tmp_path / "x.npz")]) == 2
    assert tree_hash(tmp_path / "m") == before
    assert ".npz" in capsys.readouterr().err


def test_convert_adapter_options(tmp_path):
    arrays = cf_arrays(n=5, d=3)
    arrays["pc_colors"] = np.full((5, 3), 0.5, np.float32)
    save_pointclouds(tmp_path / "m", **arrays)
    out = tmp_path / "o.npz"
    assert main(["-q", "convert", str(tmp_path / "m"), str(out), "-o", "color_range=0-1"]) == 0
    with np.load(out) as z:
        assert (z["colors"] == 128).all()


def test_convert_to_zarr_round_trips(tmp_path):
    arrays = cf_arrays(n=6, d=3)
    save_pointclouds(tmp_path / "m", **arrays)
    assert main(["-q", "convert", str(tmp_path / "m"), str(tmp_path / "m.zarr")]) == 0
    back = read_map(tmp_path / "m.zarr")
    assert back.source["adapter"] == "zarr" and back.n == 6
    np.testing.assert_array_equal(np.asarray(back.embeddings), arrays["pc_embeddings"])
    np.testing.assert_allclose(back.positions, arrays["pc_points"])


def test_convert_to_zarr_without_zarr_names_the_extra(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "zarr", None)  # import zarr now raises ImportError
    save_pointclouds(tmp_path / "m", **cf_arrays(n=6, d=3))
    assert main(["convert", str(tmp_path / "m"), str(tmp_path / "m.zarr")]) == 1
    err = capsys.readouterr().err
    assert "'zarr'" in err and "quash-plugins[dask]" in err
    assert not (tmp_path / "m.zarr").exists()


@pytest.mark.parametrize("name", ["convert"])
def test_help_lists_convert(name, capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    assert name in capsys.readouterr().out


def test_convert_carries_the_taxonomy_beside_the_map(tiny_world, tmp_path, capsys, monkeypatch):
    """A map's SRC.taxonomy.yaml (make-scene writes one) goes to DST.taxonomy.yaml, so the
    converted map finds the same sub-classes; an existing one is never replaced."""
    monkeypatch.setenv("COLUMNS", "1000")  # long temporary paths on one line
    from quash_plugins.heuristics import taxonomy_beside

    src = tiny_world["map"]
    tax = src.with_name("map.taxonomy.yaml")
    tax.write_text("chair: [armchair, stool]\nsofa: [couch]\ntable: [desk]\n")
    out = tmp_path / "copy.zarr"
    assert main(["convert", str(src), str(out)]) == 0
    assert "copy.taxonomy.yaml" in capsys.readouterr().err
    carried = tmp_path / "copy.taxonomy.yaml"
    assert carried.read_bytes() == tax.read_bytes()
    assert taxonomy_beside(read_map(out))[1] == {
        "chair": ["armchair", "stool"],
        "sofa": ["couch"],
        "table": ["desk"],
    }
    # an existing, different taxonomy beside the destination is kept, with a warning
    mine = tmp_path / "mine.taxonomy.yaml"
    mine.write_text("chair: [throne]\n")
    assert main(["convert", str(src), str(tmp_path / "mine.npz")]) == 0
    assert mine.read_text() == "chair: [throne]\n"
    assert "mine.taxonomy.yaml is kept as it is" in " ".join(capsys.readouterr().err.split())
    # no taxonomy beside the source: nothing written
    tax.unlink()
    assert main(["convert", str(src), str(tmp_path / "bare.npz")]) == 0
    assert not (tmp_path / "bare.taxonomy.yaml").exists()


def test_a_vlmaps_folder_carries_the_taxonomy_its_map_file_has(tmp_path, capsys):
    """`quash convert scene.npz vl --format vlmaps` puts the taxonomy beside
    vl/vlmap_cam/vlmaps_cam.h5df, where the taxonomy heuristics find it when `vl` is
    queried; converting `vl` on (to NPZ, or to another VLMaps folder) lost it, as only a
    taxonomy beside the SRC argument, `vl.taxonomy.yaml`, was looked for."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap
    from quash_plugins.heuristics import taxonomy_beside

    rng = np.random.default_rng(0)
    cells = np.argwhere(np.ones((3, 3, 2)))
    voxels = LatentMap(
        rng.normal(size=(len(cells), 4)).astype(np.float32),
        kind="voxels",
        positions=(cells + 0.5) * 0.25,
        grid_index=cells,
        voxel_size=0.25,
        labels=rng.integers(0, 2, len(cells)),
        label_names=["chair", "sofa"],
    )
    src = write_npz_map(voxels, tmp_path / "scene.npz")
    text = "chair: [armchair, stool]\nsofa: [couch]\n"
    src.with_name("scene.taxonomy.yaml").write_text(text)
    vl = tmp_path / "vl"
    assert main(["-q", "convert", str(src), str(vl), "--format", "vlmaps"]) == 0
    assert taxonomy_beside(read_map(vl))[1] == {"chair": ["armchair", "stool"], "sofa": ["couch"]}
    before = tree_hash(vl)

    assert main(["-q", "convert", str(vl), str(tmp_path / "back.npz")]) == 0
    assert (tmp_path / "back.taxonomy.yaml").read_text() == text
    assert main(["-q", "convert", str(vl), str(tmp_path / "vl2"), "--format", "vlmaps"]) == 0
    assert (tmp_path / "vl2" / "vlmap_cam" / "vlmaps_cam.taxonomy.yaml").read_text() == text
    assert tree_hash(vl) == before  # the source folder is only read
    capsys.readouterr()


def test_folder_maps_carry_their_taxonomy_both_ways(tiny_world, tmp_path, capsys):
    """A folder map has no suffix to replace: --format openlex3d DST gets
    DST.taxonomy.yaml beside the folder (it was logged as not carried), and a
    ConceptFusion saved-map/'s pointclouds.taxonomy.yaml goes to the NPZ's."""
    from quash_plugins.heuristics import taxonomy_beside

    text = "chair: [armchair, stool]\nsofa: [couch]\ntable: [desk]\n"
    tiny_world["map"].with_name("map.taxonomy.yaml").write_text(text)
    of = tmp_path / "of"
    assert main(["-q", "convert", str(tiny_world["map"]), str(of), "--format", "openlex3d"]) == 0
    assert (tmp_path / "of.taxonomy.yaml").read_text() == text
    assert taxonomy_beside(read_map(of))[1]["chair"] == ["armchair", "stool"]

    cf = save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=20, d=4))
    (cf.parent / "pointclouds.taxonomy.yaml").write_text(text)
    assert main(["-q", "convert", str(cf.parent), str(tmp_path / "cf.npz")]) == 0
    assert (tmp_path / "cf.taxonomy.yaml").read_text() == text
    capsys.readouterr()


@pytest.mark.parametrize(
    "dst, fmt", [("room.npz", "auto"), ("room.zarr", "auto"), ("of", "openlex3d")]
)
def test_convert_shows_progress_while_it_copies_the_embeddings(
    tmp_path, caplog, monkeypatch, dst, fmt
):
    """quash convert of a ConceptFusion map (1 GB: 11 s on 2 cores) said nothing between
    'read points map' and 'wrote'; it now logs the rows written, as queries do."""
    if dst.endswith(".zarr"):
        pytest.importorskip("zarr")
    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    monkeypatch.setattr("quash_plugins.core.progress.QUIET", False)
    save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=50, d=8))
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    convert_map(tmp_path / "saved-map", tmp_path / dst, format=fmt)
    assert "50/50 (100%" in caplog.text and "writing " in caplog.text
