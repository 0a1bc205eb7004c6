"""The Python writers never replace a file read with the map, only the map itself was.

Adapters read files beside a map (VLMaps' ``obj2cls_dict.txt``, a 2023 grid's colour,
ground-truth and obstacle grids, OpenScene's scene points, a feature file's RGB image)
and the taxonomy heuristics read ``MAP.taxonomy.yaml`` beside it. Each is recorded in
``lmap.source["inputs"]``; ``write_results_npz`` and the map writers refuse to write
over one of them, as over the map, and leave it byte for byte as it was. Each world is
written with the upstream formats' own test writers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _cf_writers import (
    cf_arrays,
    contrast_config,
    save_feat_pt,
    save_png,
    save_pointclouds,
    text_table,
)
from _vlmaps_writers import mobile_map, write_vlmaps_2d, write_vlmaps_h5df

from quash_plugins import Quash
from quash_plugins.adapters import read_map, write_npz_map
from quash_plugins.core.errors import UsageError
from quash_plugins.core.types import LatentMap
from quash_plugins.engine.results import write_results_npz

D = 8  # the text table's dimension, and every map's
TAXONOMY = "chair: [armchair]\nsofa: [couch]\ntable: [desk]\n"


def vlmaps_world(root: Path) -> tuple[Path, list[Path]]:
    """``scene/vlmap/vlmaps.h5df`` with ground truth, the scene's ``obj2cls_dict.txt``
    (two folders up, where VLMaps keeps it) and a taxonomy beside the map."""
    h5 = write_vlmaps_h5df(
        root / "scene" / "vlmap" / "vlmaps.h5df", mobile_map(d=D), semantic=np.arange(50) % 3
    )
    names = root / "scene" / "obj2cls_dict.txt"
    names.write_text("0: 0, chair\n1: 1, sofa\n2: 2, table\n")
    taxonomy = h5.with_name("vlmaps.taxonomy.yaml")
    taxonomy.write_text(TAXONOMY)
    return h5, [names, taxonomy]


def vlmaps_2d_world(root: Path) -> tuple[Path, list[Path]]:
    """A 2023 ``map/`` folder: the feature grid and the companions read beside it."""
    folder, _ = write_vlmaps_2d(root / "scene", d=D)
    companions = ["color_top_down_1.npy", "grid_1_gt.npy", "obstacles.npy"]
    return folder / "grid_lseg_1.npy", [folder / name for name in companions]


def openscene_world(root: Path) -> tuple[Path, list[Path]]:
    """OpenScene's fused features, and the scene's points found one folder over."""
    pytest.importorskip("torch")
    from _openscene_writers import preprocess_scannet, save_fused_feature

    rng = np.random.default_rng(3)
    n = 60
    pth = preprocess_scannet(
        root / "scannet_3d" / "val" / "scene0000_00_vh_clean_2.pth",
        rng.uniform(-2, 2, size=(n, 3)),
        rng.integers(0, 256, size=(n, 3)),
        rng.integers(0, 3, size=n).astype(np.float64),
    )
    (pt,) = save_fused_feature(
        rng.normal(size=(n, D)), np.arange(0, n, 2), n, root / "openseg", "scene0000_00"
    )
    return pt, [pth]


def npz_world(root: Path) -> tuple[Path, list[Path]]:
    """A portable NPZ map and the taxonomy ``quash make-scene`` writes beside it."""
    rng = np.random.default_rng(4)
    lmap = LatentMap(
        rng.normal(size=(40, D)).astype(np.float32),
        positions=rng.uniform(0, 2, size=(40, 3)).astype(np.float32),
        labels=rng.integers(0, 3, size=40),
        label_names=["chair", "sofa", "table"],
    )
    path = write_npz_map(lmap, root / "room.npz")
    taxonomy = root / "room.taxonomy.yaml"
    taxonomy.write_text(TAXONOMY)
    return path, [taxonomy]


def image_features_world(root: Path) -> tuple[Path, list[Path]]:
    """One ConceptFusion frame read by its file, its RGB image beside it."""
    pytest.importorskip("torch")
    rng = np.random.default_rng(5)
    feat = rng.normal(size=(6, 8, D)).astype(np.float16)
    pt = save_feat_pt(root / "saved-feat", "frame000000", feat)
    png = save_png(pt.with_suffix(".png"), rng.integers(0, 256, (6, 8, 3), dtype=np.uint8))
    return pt, [png]


def conceptfusion_world(root: Path) -> tuple[Path, list[Path]]:
    """A ConceptFusion ``saved-map/``, and the taxonomy beside the folder the adapter
    reads, ``pointclouds/`` (a folder has no suffix to replace: the name gets one)."""
    folder = save_pointclouds(root / "saved-map", **cf_arrays(n=40, d=D, seed=6))
    taxonomy = root / "saved-map" / "pointclouds.taxonomy.yaml"
    taxonomy.write_text(TAXONOMY)
    return folder, [taxonomy]


WORLDS = {
    "conceptfusion": conceptfusion_world,
    "vlmaps": vlmaps_world,
    "vlmaps-2d": vlmaps_2d_world,
    "openscene": openscene_world,
    "npz": npz_world,
    "image-features": image_features_world,
}


@pytest.fixture
def config(tmp_path):
    table, _ = text_table(tmp_path, D)
    return contrast_config(tmp_path, table)


@pytest.mark.parametrize("kind", sorted(WORLDS))
def test_adapters_record_the_files_they_read(tmp_path, kind):
    map_path, sides = WORLDS[kind](tmp_path)
    lmap = read_map(map_path)
    assert lmap.source["adapter"] == kind
    recorded = lmap.source["inputs"]
    assert recorded[0] == str(map_path)
    assert all(isinstance(p, str) for p in recorded)
    assert {str(p) for p in sides} <= set(recorded)


@pytest.mark.parametrize("kind", sorted(WORLDS))
def test_results_never_replace_a_file_read_with_the_map(tmp_path, config, kind):
    map_path, sides = WORLDS[kind](tmp_path)
    quash = Quash.from_config(config)
    lmap = quash.read_map(map_path)
    results = quash.query_many(lmap, ["chair", "sofa"])
    for side in sides:
        before = side.read_bytes()
        for given in ({}, {"lmap": lmap}):
            with pytest.raises(UsageError) as err:
                write_results_npz(side, results, **given)
            said = str(err.value)
            assert said.startswith(f"Output {side} is the input ")
            assert side.name in said.split(" is the input ")[1]
            assert said.endswith("Choose another output file.")
            assert side.read_bytes() == before
    assert sorted(p.name for p in tmp_path.rglob(".*")) == []  # no temporary file left
    out = write_results_npz(tmp_path / "out" / "result.npz", results, lmap=lmap)
    with np.load(out) as z:
        assert list(z["queries"]) == ["chair", "sofa"]
        assert z["masks"].shape == (2, lmap.n)
        assert np.array_equal(z["masks"][0], results[0].mask)


def test_map_writers_refuse_the_maps_side_files(tmp_path):
    from quash_plugins.adapters import convert_map
    from quash_plugins.adapters._convert import write_npz_streaming

    h5, (names, taxonomy) = vlmaps_world(tmp_path)
    lmap = read_map(h5)
    for side in (names, taxonomy):
        before = side.read_bytes()
        for write in (write_npz_map, write_npz_streaming):
            with pytest.raises(UsageError, match="is the input"):
                write(lmap, side)
        assert side.read_bytes() == before
    assert read_map(convert_map(h5, tmp_path / "copy.npz")).n == lmap.n


def test_vlmaps_export_never_replaces_the_label_file_it_read(tmp_path):
    """``--format vlmaps`` writes ``DIR/vlmap_cam/obj2cls_dict.txt``: never over the
    label-name file the map was read with."""
    from quash_plugins.adapters import convert_map

    h5, _ = vlmaps_world(tmp_path)
    other = tmp_path / "other"
    labels = other / "vlmap_cam" / "obj2cls_dict.txt"
    labels.parent.mkdir(parents=True)
    labels.write_text("chair\nsofa\ntable\n")
    before = labels.read_bytes()
    with pytest.raises(UsageError, match="is the input"):
        convert_map(h5, other, format="vlmaps", label_names=str(labels), positions="upstream")
    assert labels.read_bytes() == before
    assert not (other / "vlmap_cam" / "vlmaps_cam.h5df").exists()
    written = convert_map(
        h5, tmp_path / "fresh", format="vlmaps", label_names=str(labels), positions="upstream"
    )
    assert read_map(written).label_names == ["chair", "sofa", "table"]


def test_a_callers_own_map_keeps_the_taxonomy_beside_its_path(tmp_path):
    """A map made in memory records only its ``path``: the taxonomy beside that path is
    still refused, since the taxonomy heuristics read it."""
    path, (taxonomy,) = npz_world(tmp_path)
    lmap = LatentMap(np.eye(3, D, dtype=np.float32), source={"path": str(path)})
    before = taxonomy.read_bytes()
    with pytest.raises(UsageError, match="is the input"):
        write_npz_map(lmap, taxonomy)
    assert taxonomy.read_bytes() == before
    assert read_map(write_npz_map(lmap, tmp_path / "mine.npz")).n == 3


def test_the_taxonomy_beside_a_folder_map_is_read(tmp_path):
    """A folder map (ConceptFusion's saved-map/pointclouds/) has no suffix: its taxonomy
    is pointclouds.taxonomy.yaml beside that folder, found as a file map's is (it was
    never looked for), whether the map is named by saved-map/ or by the folder itself;
    a suffixed folder keeps the suffix rule (store.zarr: store.taxonomy.yaml)."""
    from quash_plugins.heuristics import taxonomy_beside, taxonomy_path_beside

    folder, [taxonomy] = conceptfusion_world(tmp_path)
    assert taxonomy_beside(read_map(folder.parent)) is not None
    found = taxonomy_beside(read_map(folder))
    assert found is not None
    assert found[0] == str(taxonomy) and found[1]["chair"] == ["armchair"]
    assert taxonomy_path_beside(tmp_path / "store.zarr") == tmp_path / "store.taxonomy.yaml"
    assert taxonomy_path_beside(f"{folder}/") == taxonomy
