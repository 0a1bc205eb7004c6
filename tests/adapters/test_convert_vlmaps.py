"""``quash convert --format vlmaps``: a map written in VLMaps' own HDF5 save layout."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
from _vlmaps_writers import CAMERA_FIELDS

from quash_plugins.adapters import read_map
from quash_plugins.cli.main import main
from quash_plugins.core.errors import MapFormatError, UsageError

h5py = pytest.importorskip("h5py")

#: What VLMaps' camera-base ``save_3d_map`` writes (``VLMapBuilderCam``).
UPSTREAM = set(CAMERA_FIELDS)


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _y_up(points):
    """A z-up map's points turned to VLMaps' camera-base y-up frame: (x, z, -y)."""
    x, y, z = np.asarray(points, dtype=np.float64).T
    return np.column_stack([x, z, -y])


def test_make_scene_round_trips_through_vlmaps(minilm_scene, tmp_path):
    before = _digest(minilm_scene)
    vl = tmp_path / "vl"
    assert main(["-q", "convert", str(minilm_scene), str(vl), "--format", "vlmaps"]) == 0
    h5 = vl / "vlmap_cam" / "vlmaps_cam.h5df"
    src = read_map(minilm_scene)
    with h5py.File(h5, "r") as f:
        assert set(f) >= UPSTREAM and set(f) - UPSTREAM == {"grid_semantic"}
        assert f["grid_pos"].dtype == np.int32 and f["grid_rgb"].dtype == np.uint8
        assert f["cs"][()] == 0.2  # the number the user gave, not float32's 0.2000000003
        occupied = f["occupied_ids"][()]
        grid_pos = f["grid_pos"][()]
        n = len(grid_pos)
        assert (occupied[tuple(grid_pos.T)] == np.arange(n)).all()
        assert (occupied >= 0).sum() == n
    # VLMaps' camera-base layout: cells [row, height, col], height on axis 1, +y up
    # (VLMapBuilderCam keeps, per (row, col), the point of largest height)
    idx = np.asarray(src.grid_index)
    assert occupied.shape == tuple(np.ptp(idx, axis=0)[[0, 2, 1]] + 1)
    np.testing.assert_array_equal(grid_pos[:, 1], idx[:, 2] - idx[:, 2].min())
    back = read_map(vl)
    assert back.source["adapter"] == "vlmaps" and back.source["pose_type"] == "camera_base"
    assert back.source["up"] == "+y"
    np.testing.assert_array_equal(back.embeddings[()], np.asarray(src.embeddings))
    np.testing.assert_allclose(back.positions, _y_up(src.positions), atol=1e-5)
    np.testing.assert_array_equal(back.labels, src.labels)
    assert back.label_names == src.label_names
    np.testing.assert_array_equal(back.colors, src.colors)
    assert back.voxel_size == pytest.approx(src.voxel_size)
    # the origin reads back as the number it is, not 3e-9 of float rounding
    assert (np.asarray(src.grid_index).min(axis=0) == 0).all()
    # (float32's -4.4000001 is -4.4 to the micrometre)
    assert back.source["pcd_min"] == np.round(_y_up(src.positions).min(axis=0), 6).tolist()
    # the encoder record survives, so a query with another encoder still warns
    assert src.source["encoder"] == "minilm"
    for key in ("encoder", "encoder_fingerprint"):
        assert back.source[key] == src.source[key]
    assert _digest(minilm_scene) == before

    # the same query on both gives the same rows: the sub-classes beside scene.npz are
    # copied beside the converted file, where the taxonomy heuristic finds them
    tax = minilm_scene.with_name("scene.taxonomy.yaml")
    carried = h5.with_name("vlmaps_cam.taxonomy.yaml")
    assert carried.read_text(encoding="utf-8") == tax.read_text(encoding="utf-8")
    cfg = tmp_path / "quash.yaml"
    cfg.write_text(
        "encoder: minilm\n"
        "heuristic: {name: taxonomy, n_synonyms: 20, n_antonyms: all}\n"
        "classifier: {name: nearest-sample, k: 2}\n"
        "refine: {classifier: svm-rbf, n_positives: 100, n_negatives: 1000, seeds: top}\n"
    )
    r0, r1 = tmp_path / "r0.npz", tmp_path / "r1.npz"
    for m, r in ((minilm_scene, r0), (vl, r1)):
        assert main(["-q", "query", str(m), "chair", "-c", str(cfg), "--out", str(r)]) == 0
    with np.load(r0) as a, np.load(r1) as b:
        assert a["masks"].any()
        for z in (a, b):  # each found its map's taxonomy: the query has its sub-classes
            record = json.loads(str(z["provenance"]))["queries"][0]
            assert record["labels_from"].endswith(".taxonomy.yaml"), record["labels_from"]
        np.testing.assert_array_equal(a["masks"], b["masks"])
        np.testing.assert_allclose(a["scores"], b["scores"], atol=1e-3)  # rows re-normalised
        mask, scores = a["masks"][0], a["scores"][0]
    # cells keep their neighbours: the same mask groups into the same objects, turned
    from quash_plugins.engine import find_instances

    found = [find_instances(m, mask, scores, max_instances=None) for m in (src, back)]
    assert len(found[0]) > 1
    assert [i.size for i in found[0]] == [i.size for i in found[1]]
    np.testing.assert_allclose(
        [i.centroid for i in found[1]], _y_up([i.centroid for i in found[0]]), atol=1e-4
    )


def test_vlmaps_format_refuses_a_map_without_a_voxel_grid(tiny_world, capsys):
    dst = tiny_world["dir"] / "vl"
    assert main(["convert", str(tiny_world["map"]), str(dst), "--format", "vlmaps"]) != 0
    err = capsys.readouterr().err
    assert "map.npz" in err and "voxel grid" in err and "grid_index" in err
    assert not dst.exists()


def _grid_map(path):
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(1)
    idx = np.stack(np.unravel_index(rng.choice(200, 12, replace=False), (5, 5, 8)), 1)
    pos = (np.array([-1.0, 2.0, 0.5]) + idx * 0.05).astype(np.float32)
    emb = rng.normal(size=(12, 4)).astype(np.float16)
    return write_npz_map(
        LatentMap(emb, kind="voxels", positions=pos, grid_index=idx, voxel_size=0.05), path
    )


def test_vlmaps_format_keeps_float16_and_the_origin(tmp_path):
    src = _grid_map(tmp_path / "g.npz")
    assert main(["-q", "convert", str(src), str(tmp_path / "vl"), "--format", "vlmaps"]) == 0
    back, orig = read_map(tmp_path / "vl"), read_map(src)
    assert back.embeddings.dtype == np.float16 and back.labels is None
    np.testing.assert_array_equal(back.embeddings[()], orig.embeddings)
    np.testing.assert_allclose(back.positions, _y_up(orig.positions), atol=1e-6)
    assert not (tmp_path / "vl" / "vlmap_cam" / "obj2cls_dict.txt").exists()


def test_vlmaps_format_needs_force_and_never_writes_its_input(tmp_path, capsys):
    src = _grid_map(tmp_path / "g.npz")
    vl = tmp_path / "vl"
    args = ["-q", "convert", str(src), str(vl), "--format", "vlmaps"]
    assert main(args) == 0
    h5 = vl / "vlmap_cam" / "vlmaps_cam.h5df"
    first = _digest(h5)
    assert main(args) == 2
    assert "--force" in capsys.readouterr().err and _digest(h5) == first
    assert main([*args, "--force"]) == 0
    # the VLMaps file itself as the input, written back into its own scene folder
    again = ["-q", "convert", str(h5), str(vl), "--format", "vlmaps", "--force"]
    assert main(again) == 2
    assert "input" in capsys.readouterr().err
    assert main(["-q", "convert", str(vl), str(tmp_path / "x.npz")]) == 0  # still readable
    # a .npz destination is not a scene folder
    assert main(["-q", "convert", str(src), str(tmp_path / "y.npz"), "--format", "vlmaps"]) == 2


def test_force_leaves_no_label_files_of_the_map_it_replaced(tmp_path, capsys):
    """`convert a.npz vl --format vlmaps`, then `convert b.npz vl ... --force` with a map
    that has labels but neither names nor a taxonomy: vl read back with a's label names
    (its obj2cls_dict.txt) and a's taxonomy, silently."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap
    from quash_plugins.heuristics import taxonomy_beside

    rng = np.random.default_rng(0)
    cells = np.argwhere(np.ones((3, 3, 2)))

    def labelled(names):
        return LatentMap(
            rng.normal(size=(len(cells), 4)).astype(np.float32),
            kind="voxels",
            positions=(cells + 0.5) * 0.25,
            grid_index=cells,
            voxel_size=0.25,
            labels=rng.integers(0, 2, len(cells)),
            label_names=names,
        )

    a = write_npz_map(labelled(["chair", "sofa"]), tmp_path / "a.npz")
    a.with_name("a.taxonomy.yaml").write_text("chair: [stool]\nsofa: [couch]\n")
    b = write_npz_map(labelled(None), tmp_path / "b.npz")
    vl = tmp_path / "vl"
    assert main(["-q", "convert", str(a), str(vl), "--format", "vlmaps"]) == 0
    assert read_map(vl).label_names == ["chair", "sofa"]
    capsys.readouterr()
    assert main(["convert", str(b), str(vl), "--format", "vlmaps", "--force"]) == 0
    back = read_map(vl)
    assert back.labels is not None and back.label_names is None
    assert not (vl / "vlmap_cam" / "obj2cls_dict.txt").exists()
    err = " ".join(capsys.readouterr().err.split())
    assert "vlmaps_cam.taxonomy.yaml is beside the converted map" in err
    assert "b.npz has no taxonomy" in err
    assert taxonomy_beside(back) is not None  # kept: a taxonomy file is never removed


def test_vlmaps_format_turns_only_what_is_not_y_up(tmp_path):
    """A map that is y-up already (a camera-base VLMaps map) is written as it is; one
    whose up axis is not an axis is refused, naming the field."""
    from quash_plugins.adapters._vlmaps_write import write_vlmaps_map

    src = _grid_map(tmp_path / "g.npz")
    assert main(["-q", "convert", str(src), str(tmp_path / "vl"), "--format", "vlmaps"]) == 0
    first = read_map(tmp_path / "vl")
    again = ["-q", "convert", str(tmp_path / "vl"), str(tmp_path / "vl2"), "--format", "vlmaps"]
    assert main(again) == 0
    second = read_map(tmp_path / "vl2")
    assert second.source["up"] == "+y"
    np.testing.assert_allclose(second.positions, first.positions, atol=1e-6)
    np.testing.assert_array_equal(second.grid_index, first.grid_index)
    # through the portable NPZ (and a Zarr store) the up axis goes along, so the map is
    # not turned twice on the way back, and the viewer still sees it from above
    assert main(["-q", "convert", str(tmp_path / "vl"), str(tmp_path / "y.npz")]) == 0
    via_npz = read_map(tmp_path / "y.npz")
    assert via_npz.source["up"] == "+y"
    back = ["-q", "convert", str(tmp_path / "y.npz"), str(tmp_path / "vl4"), "--format", "vlmaps"]
    assert main(back) == 0
    np.testing.assert_allclose(read_map(tmp_path / "vl4").positions, first.positions, atol=1e-6)
    odd = read_map(src)
    odd.source["up"] = "sideways"
    with pytest.raises(UsageError, match=r"g\.npz.*source\['up'\].*'sideways'"):
        write_vlmaps_map(odd, tmp_path / "vl3")
    assert not (tmp_path / "vl3").exists()


def test_npz_up_axis_that_is_not_an_axis_is_refused(tmp_path):
    bad = tmp_path / "bad.npz"
    np.savez(bad, embeddings=np.eye(3, dtype=np.float32), up=np.asarray("sideways"))
    with pytest.raises(MapFormatError, match=r"bad\.npz.*'up'.*'sideways'.*\+z"):
        read_map(bad)


def test_convert_up_names_the_axis_a_format_does_not_record(tmp_path):
    """``--up``: a y-up map whose format records no axis (the portable NPZ without
    ``up``) is written as VLMaps' y-up cells unturned, and the axis goes into an NPZ."""
    from quash_plugins.adapters import convert_map

    src = _grid_map(tmp_path / "g.npz")  # no 'up': +z would be assumed
    orig = read_map(src)
    vl = ["-q", "convert", str(src), str(tmp_path / "vl"), "--format", "vlmaps", "--up", "+y"]
    assert main(vl) == 0
    back = read_map(tmp_path / "vl")
    assert back.source["up"] == "+y"
    np.testing.assert_allclose(back.positions, orig.positions, atol=1e-6)
    np.testing.assert_array_equal(back.grid_index, orig.grid_index - orig.grid_index.min(0))
    assert main(["-q", "convert", str(src), str(tmp_path / "y.npz"), "--up=-y"]) == 0
    assert read_map(tmp_path / "y.npz").source["up"] == "-y"
    assert "up" not in orig.source  # a map given to convert_map keeps its own source
    convert_map(orig, tmp_path / "x.npz", up="+x")
    assert "up" not in orig.source and read_map(tmp_path / "x.npz").source["up"] == "+x"
    with pytest.raises(UsageError, match=r"up axis 'y'.*\+y"):
        convert_map(src, tmp_path / "z.npz", up="y")


def test_the_docs_say_where_convert_puts_the_taxonomy():
    """docs/vlmaps.md said `quash query vl` could not see make-scene's sub-classes after
    `quash convert --format vlmaps`, and docs/adapters.md that no taxonomy is carried to
    a VLMaps folder; convert copies it beside vlmaps_cam.h5df (checked above)."""
    docs = Path(__file__).resolve().parents[2] / "docs"
    for page in ("vlmaps.md", "adapters.md"):
        text = " ".join((docs / page).read_text(encoding="utf-8").split())
        assert "vlmap_cam/vlmaps_cam.taxonomy.yaml" in text, page
        assert "does not see them" not in text and "`--format openlex3d`, `vlmaps`)" not in text
