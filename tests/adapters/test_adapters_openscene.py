"""``openscene``: fused features written the way OpenScene's scripts write them."""

from __future__ import annotations

import logging
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
import yaml
from _cf_writers import tree_hash
from _openscene_writers import (
    preprocess_matterport,
    preprocess_nuscenes,
    preprocess_scannet,
    save_fused_feature,
)

from quash_plugins import Quash
from quash_plugins.adapters import detect_adapter, read_map
from quash_plugins.core import registry
from quash_plugins.core.errors import EmptyMapWarning, MapFormatError

torch = pytest.importorskip("torch")

NAMES = ["wall", "floor", "chair", "table"]


def scannet_scene(root, n=400, d=768, seed=0, visible=0.85, n_files=1, n_split=2_000_000):
    """``root/scannet_3d/val/<scene>_vh_clean_2.pth`` + ``root/openseg/<scene>_<n>.pt``."""
    rng = np.random.default_rng(seed)
    coords = rng.uniform(-3, 3, size=(n, 3))
    rgb = rng.integers(0, 256, size=(n, 3))
    labels = rng.integers(0, len(NAMES), size=n).astype(np.float64)
    labels[rng.random(n) < 0.1] = 255
    feat_bank = rng.normal(size=(n, d)) * rng.uniform(0.2, 3, size=(n, 1))
    point_ids = np.flatnonzero(rng.random(n) < visible)
    pth = preprocess_scannet(
        Path(root) / "scannet_3d" / "val" / "scene0011_00_vh_clean_2.pth", coords, rgb, labels
    )
    pts = save_fused_feature(
        feat_bank, point_ids, n, Path(root) / "openseg", "scene0011_00", n_files, n_split, seed
    )
    return {"pth": pth, "pts": pts, "coords": coords, "rgb": rgb, "labels": labels,
            "feat_bank": feat_bank}  # fmt: skip


def names_file(tmp_path):
    path = tmp_path / "scannet_labels.txt"
    path.write_text("\n".join(NAMES) + "\n")
    return path


def read_all(lmap, rows=37):
    return np.concatenate([b for _, _, b in lmap.iter_chunks(rows)])


def unit(x):
    x = np.asarray(x, np.float64)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def test_scannet_val_scene(tmp_path):
    s = scannet_scene(tmp_path / "data")
    pt = s["pts"][0]
    before = tree_hash(tmp_path / "data")
    assert detect_adapter(pt) == "openscene"
    lmap = read_map(pt, label_names=str(names_file(tmp_path)))
    saved = torch.load(pt, weights_only=True)
    mask = saved["mask_full"].numpy()
    assert lmap.kind == "points" and lmap.n == 400 and lmap.dim == 768
    assert lmap.dtype == np.float16  # stays float16 on disk and in the map
    assert lmap.source["points"] == str(s["pth"]) and lmap.source["scene"] == "scene0011_00"
    np.testing.assert_array_equal(lmap.positions, s["coords"].astype(np.float32))
    np.testing.assert_array_equal(lmap.colors, s["rgb"])  # (rgb/127.5 - 1 + 1) * 127.5
    expected_labels = np.where(s["labels"] == 255, -1, s["labels"]).astype(np.int64)
    np.testing.assert_array_equal(lmap.labels, expected_labels)
    assert lmap.label_names == NAMES
    # row j of feat is the j-th True point; points without a feature are zero rows
    expected = np.zeros((400, 768))
    expected[mask] = saved["feat"].float().numpy()
    np.testing.assert_allclose(read_all(lmap), unit(expected), atol=1e-6)
    assert not read_all(lmap)[~mask].any()
    only = read_map(pt, all_points=False)
    assert only.n == int(mask.sum()) == lmap.source["featured_points"]
    np.testing.assert_array_equal(only.positions, s["coords"][mask].astype(np.float32))
    np.testing.assert_array_equal(np.asarray(only.embeddings), saved["feat"].numpy())
    assert tree_hash(tmp_path / "data") == before


def test_training_files_are_random_subsets(tmp_path):
    s = scannet_scene(tmp_path, n=300, d=16, n_files=3, n_split=120)
    masks = []
    for pt in s["pts"]:
        lmap = read_map(pt, all_points=False)
        assert lmap.n <= 120
        masks.append(torch.load(pt, weights_only=True)["mask_full"].numpy())
        np.testing.assert_array_equal(lmap.positions, s["coords"][masks[-1]].astype(np.float32))
    assert not np.array_equal(masks[0], masks[1])


def test_matterport_nuscenes_and_other_point_sources(tmp_path):
    rng = np.random.default_rng(3)
    n, d = 80, 12
    coords = rng.uniform(-1, 1, (n, 3))
    labels = rng.integers(0, 21, n)
    labels[:5] = 255
    feats = rng.normal(size=(n, d))
    mp = preprocess_matterport(tmp_path / "mp" / "17DRP5sb8fy_region0.pth", coords,
                               rng.integers(0, 256, (n, 3)), labels)  # fmt: skip
    [pt] = save_fused_feature(feats, np.arange(n), n, tmp_path / "mp", "17DRP5sb8fy_region0")
    lmap = read_map(pt)
    assert lmap.source["points"] == str(mp)
    np.testing.assert_array_equal(lmap.labels, np.where(labels == 255, -1, labels))
    # nuScenes: <scene>.pt, no colours in the .pth (a scalar 0)
    nu = preprocess_nuscenes(tmp_path / "nu" / "points" / "scene-0001.pth", coords, labels)
    mask = torch.from_numpy(rng.random(n) < 0.5)
    torch.save({"feat": torch.from_numpy(feats)[mask].half(), "mask_full": mask},
               tmp_path / "nu" / "scene-0001.pt")  # fmt: skip
    lmap = read_map(tmp_path / "nu" / "scene-0001.pt", "openscene")
    assert lmap.colors is None and lmap.source["points"] == str(nu)
    # a .npy of coordinates, and a .ply, named explicitly
    np.save(tmp_path / "xyz.npy", coords)
    lmap = read_map(pt, points=str(tmp_path / "xyz.npy"))
    np.testing.assert_array_equal(lmap.positions, coords.astype(np.float32))
    assert lmap.labels is None
    o3d = pytest.importorskip("open3d")
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(coords)
    cloud.colors = o3d.utility.Vector3dVector(np.full((n, 3), 0.5))
    o3d.io.write_point_cloud(str(tmp_path / "scene.ply"), cloud)
    lmap = read_map(pt, points=str(tmp_path / "scene.ply"))
    np.testing.assert_allclose(lmap.positions, coords, atol=1e-6)
    assert (lmap.colors == 128).all()


def test_per_point_numpy_features(tmp_path):
    s = scannet_scene(tmp_path, n=50, d=8)
    feats = np.random.default_rng(1).normal(size=(50, 8)).astype(np.float32)
    path = tmp_path / "openseg" / "scene0011_00_openscene_feat_ensemble.npy"
    np.save(path, feats)
    assert detect_adapter(path) == "openscene"
    lmap = read_map(path)
    assert lmap.n == 50 and lmap.source["points"] == str(s["pth"])
    np.testing.assert_allclose(read_all(lmap), unit(feats), atol=1e-6)


class Payload:
    """Unpickling this runs a command: a stand-in for a malicious scene file."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


def test_malicious_pickles_are_refused(tmp_path):
    s = scannet_scene(tmp_path, n=40, d=8)
    pt, good_pt = s["pts"][0], s["pts"][0].read_bytes()
    marker = tmp_path / "pwned"
    torch.save((s["coords"], Payload(marker), s["labels"]), s["pth"])
    before = tree_hash(tmp_path)
    with pytest.raises(MapFormatError) as err:
        read_map(pt)
    assert "scene0011_00_vh_clean_2.pth" in str(err.value) and "system" in str(err.value)
    assert not marker.exists() and tree_hash(tmp_path) == before
    torch.save({"feat": torch.zeros(3, 8), "mask_full": Payload(marker)}, pt)
    with pytest.raises(MapFormatError, match=r"scene0011_00_0\.pt.*system"):
        read_map(pt, "openscene")
    assert not marker.exists()
    pt.write_bytes(good_pt)
    with open(tmp_path / "plain.pth", "wb") as fh:  # a raw pickle, not torch's zip format
        pickle.dump((s["coords"], Payload(marker)), fh)
    with pytest.raises(MapFormatError, match=r"plain\.pth: refused"):
        read_map(pt, "openscene", points=str(tmp_path / "plain.pth"))
    assert not marker.exists()


def test_bad_input_names_file_and_field(tmp_path):
    s = scannet_scene(tmp_path, n=40, d=8)
    pt = s["pts"][0]
    other = preprocess_scannet(tmp_path / "other.pth", s["coords"][:30], s["rgb"][:30],
                               s["labels"][:30])  # fmt: skip
    with pytest.raises(MapFormatError, match=r"mask_full.*40.*other\.pth.*30"):
        read_map(pt, points=str(other))
    lonely = tmp_path / "elsewhere" / "deep" / "scene0099_00_0.pt"
    lonely.parent.mkdir(parents=True)
    torch.save(torch.load(pt, weights_only=True), lonely)
    with pytest.raises(MapFormatError, match=r"scene0099_00\.pth.*points=PATH"):
        read_map(lonely)
    saved = torch.load(pt, weights_only=True)
    torch.save({"feat": saved["feat"][:-1], "mask_full": saved["mask_full"]}, pt)
    with pytest.raises(MapFormatError, match=r"'feat' has \d+ rows but 'mask_full' marks"):
        read_map(pt)
    torch.save({"features": saved["feat"]}, pt)
    with pytest.raises(MapFormatError, match=r"'feat'.*'mask_full'"):
        read_map(pt, "openscene")
    with pytest.raises(MapFormatError, match=r"nope\.pth: points file not found"):
        read_map(lonely, points=str(tmp_path / "nope.pth"))


def test_sniff_tells_fused_files_from_frame_features(tmp_path):
    s = scannet_scene(tmp_path, n=20, d=8)
    frame = tmp_path / "saved-feat" / "frame000000.pt"
    frame.parent.mkdir()
    torch.save(torch.zeros(4, 5, 8, dtype=torch.float16), frame)
    adapter = registry.create("adapters", "openscene")
    assert adapter.sniff(s["pts"][0]) and not adapter.sniff(frame)
    assert detect_adapter(frame) == "image-features"
    assert not adapter.sniff(s["pth"]) and not adapter.sniff(tmp_path)


def test_a_folder_of_fused_files_is_not_taken_for_per_image_features(tmp_path):
    """OpenScene's folder of fused <scene>_<n>.pt was sniffed as image-features (it holds
    a .pt): the image-features error said to use --adapter openscene, which said the folder
    looked like an image-features map. No adapter takes the folder; the error names the
    fused file inside it, with its adapter, and openscene's error names no other adapter."""
    s = scannet_scene(tmp_path, n=20, d=8)
    folder = s["pts"][0].parent
    assert not registry.create("adapters", "image-features").sniff(folder)
    with pytest.raises(MapFormatError) as err:
        detect_adapter(folder)
    assert f"{s['pts'][0]} (openscene); pass one of them" in str(err.value)
    with pytest.raises(MapFormatError) as err:
        read_map(folder, "openscene")
    assert "image-features" not in str(err.value)
    # a folder of frames beside a fused file is still a feature folder
    torch.save(torch.zeros(4, 5, 8), folder / "frame000000.pt")
    assert registry.create("adapters", "image-features").sniff(folder)


def test_the_scene_points_passed_as_the_map_say_to_pass_the_fused_features(tmp_path):
    """<scene>_vh_clean_2.pth given as the map was read as a per-image feature map, whose
    error said to re-save 'the frame' as a tensor; --adapter openscene said it looked like
    an image-features map. Both now say what it is and to pass the fused <scene>_<n>.pt."""
    s = scannet_scene(tmp_path, n=20, d=8)
    for adapter in ("auto", "openscene"):
        with pytest.raises(MapFormatError) as err:
            read_map(s["pth"], adapter)
        msg = str(err.value)
        assert f"{s['pth']} holds numpy arrays" in msg and "<scene>_<n>.pt" in msg
        assert "Re-save the frame" not in msg and "It looks like" not in msg
    assert detect_adapter(s["pts"][0]) == "openscene"  # the fused file itself is unchanged
    frame = tmp_path / "frame000000.pth"  # a frame's bare tensor as .pth is still a frame
    torch.save(torch.zeros(4, 5, 8), frame)
    assert detect_adapter(frame) == "image-features"


def test_a_fused_file_missing_one_field_is_refused_naming_it(tmp_path, capsys):
    """A <scene>_<n>.pt with only 'feat' (or only 'mask_full') is OpenScene's, not a
    per-image feature map: auto-detection reads it as openscene, and the error names the
    missing field and what to write (it was taken for image-features, whose error told
    the user to save the dict's tensor as a frame, or refused -o points)."""
    from quash_plugins.cli.main import main

    s = scannet_scene(tmp_path, n=40, d=8)
    saved = torch.load(s["pts"][0], weights_only=True)
    only_feat = tmp_path / "openseg" / "scene0011_00_1.pt"
    torch.save({"feat": saved["feat"]}, only_feat)
    only_mask = tmp_path / "openseg" / "scene0011_00_2.pt"
    torch.save({"mask_full": saved["mask_full"]}, only_mask)
    before = tree_hash(tmp_path)
    assert detect_adapter(only_feat) == detect_adapter(only_mask) == "openscene"
    with pytest.raises(MapFormatError) as err:
        read_map(only_feat)
    msg = str(err.value)
    assert "scene0011_00_1.pt" in msg and "field 'mask_full' missing" in msg
    assert "_openscene_feat_" in msg and "image-features" not in msg
    with pytest.raises(MapFormatError, match=r"scene0011_00_2\.pt: field 'feat' missing"):
        read_map(only_mask, "openscene")
    out = tmp_path / "out.npz"
    args = ["convert", str(only_feat), str(out), "-o", f"points={s['pth']}"]
    assert main(args) == 1  # a map that cannot be read
    err_text = capsys.readouterr().err
    assert "field 'mask_full' missing" in err_text and "does not accept" not in err_text
    assert not out.exists() and tree_hash(tmp_path) == before
    # a frame's bare tensor is still a per-image feature map
    frame = tmp_path / "saved-feat" / "frame000000.pt"
    frame.parent.mkdir()
    torch.save(torch.zeros(4, 5, 8), frame)
    assert detect_adapter(frame) == "image-features"


def test_nothing_fused_and_empty_maps(tmp_path):
    s = scannet_scene(tmp_path, n=30, d=8, visible=0.0)
    pt = s["pts"][0]
    assert torch.load(pt, weights_only=True)["feat"].shape == (0, 8)
    lmap = read_map(pt)
    assert lmap.n == 30 and not read_all(lmap).any()  # every point unobserved
    empty = read_map(pt, all_points=False)
    assert (empty.n, empty.dim) == (0, 8)
    table = {
        w: np.eye(8)[i].tolist() for i, w in enumerate(["chair", "other", "background", "nothing"])
    }
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(table))
    cfg = tmp_path / "q.yaml"
    cfg.write_text("encoder: {name: table, file: t.yaml}\nclassifier: contrast\ncache: false\n")
    assert not Quash.from_config(cfg).query(lmap, "chair").mask.any()
    with pytest.warns(EmptyMapWarning):
        assert Quash.from_config(cfg).query(empty, "chair").mask.shape == (0,)


def test_end_to_end_cli_query(tmp_path):
    """OpenScene's own evaluation is an argmax of the fused features against the label
    texts; here the label-argmax baseline over the label names gives the same mask."""
    from quash_plugins.cli.main import main

    rng = np.random.default_rng(5)
    n, d = 200, 16
    lab = rng.integers(0, len(NAMES), n)
    T = np.linalg.qr(rng.normal(size=(d, d)))[0][: len(NAMES) + 1]
    feat_bank = (T[lab] + 0.1 * rng.normal(size=(n, d))) * rng.uniform(0.5, 2, (n, 1))
    coords = rng.uniform(-2, 2, (n, 3))
    preprocess_scannet(tmp_path / "scannet_3d" / "val" / "scene0000_00_vh_clean_2.pth", coords,
                       rng.integers(0, 256, (n, 3)), lab)  # fmt: skip
    [pt] = save_fused_feature(feat_bank, np.arange(n), n, tmp_path / "fused", "scene0000_00")
    table = {w: T[i].tolist() for i, w in enumerate([*NAMES, "other"])}
    (tmp_path / "t.yaml").write_text(yaml.safe_dump(table))
    cfg = tmp_path / "openscene.yaml"
    cfg.write_text(
        "encoder: {name: table, file: t.yaml}\nheuristic: none\nclassifier: label-argmax\n"
        f"negatives: [{', '.join(n for n in NAMES if n != 'chair')}, other]\ncache: false\n"
    )
    out = tmp_path / "r.npz"
    assert main(["query", str(pt), "chair", "-c", str(cfg), "--out", str(out)]) == 0
    feats = torch.load(pt, weights_only=True)["feat"].float().numpy()
    reference = np.argmax(feats @ T[: len(NAMES)].T, axis=1) == NAMES.index("chair")
    with np.load(out) as z:
        np.testing.assert_array_equal(z["masks"][0], reference)
        assert reference.sum() > 20


def test_allow_list_is_narrow_and_reads_numpy1_pickles(tmp_path):
    import zipfile

    from quash_plugins.adapters._openscene import numpy_allow_list

    for entry in numpy_allow_list():
        obj, name = entry if isinstance(entry, tuple) else (entry, None)
        module = name.rsplit(".", 1)[0] if name else obj.__module__
        assert module.split(".")[0] == "numpy", entry
    # a .pth pickled under numpy 1.x names numpy.core.multiarray._reconstruct
    s = scannet_scene(tmp_path, n=30, d=8)
    data = {}
    with zipfile.ZipFile(s["pth"]) as z:
        for info in z.infolist():
            data[info.filename] = z.read(info.filename)
    key = next(k for k in data if k.endswith("data.pkl"))
    assert b"numpy._core.multiarray" in data[key]
    data[key] = data[key].replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    with zipfile.ZipFile(s["pth"], "w") as z:
        for name, blob in data.items():
            z.writestr(name, blob)
    lmap = read_map(s["pts"][0])
    np.testing.assert_array_equal(lmap.positions, s["coords"].astype(np.float32))


def _pth_with_colors(path, coords, colors, labels):
    """A ``.pth`` tuple as OpenScene's preprocessing writes it, with given colours."""
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save((np.asarray(coords, np.float64), colors, np.asarray(labels, np.float64)), path)
    return path


def test_colours_in_0_255_are_refused_not_read_white(tmp_path):
    """A ``.pth`` whose colours are 0-255 (not ``rgb / 127.5 - 1``) read all white, without
    a word; it is refused naming the file, the field and the fix."""
    s = scannet_scene(tmp_path, n=30, d=8)
    _pth_with_colors(s["pth"], s["coords"], s["rgb"].astype(np.float64), s["labels"])
    before = tree_hash(tmp_path)
    with pytest.raises(MapFormatError) as info:
        read_map(s["pts"][0])
    msg = str(info.value)
    assert str(s["pth"]) in msg and "field 'colors'" in msg and "[-1, 1]" in msg
    assert f"to {s['rgb'].max():.4g}" in msg and "0-255" in msg and "/ 127.5 - 1" in msg
    assert "points=PATH" in msg and tree_hash(tmp_path) == before


def test_colours_a_little_out_of_range_are_clipped_with_one_warning(tmp_path, caplog):
    s = scannet_scene(tmp_path, n=30, d=8)
    colors = s["rgb"] / 127.5 - 1
    colors[0] = [1.04, -1.02, 0.0]  # e.g. after an augmentation step
    colors[5, 2] = 1.2
    _pth_with_colors(s["pth"], s["coords"], colors, s["labels"])
    with caplog.at_level(logging.WARNING, logger="quash_plugins"):
        lmap = read_map(s["pts"][0])
        again = read_map(s["pts"][0])
    said = [r.getMessage() for r in caplog.records if "field 'colors'" in r.getMessage()]
    assert len(said) == 1, said  # once per file
    assert str(s["pth"]) in said[0] and "3 of 90 values outside" in said[0]
    expected = np.clip(np.rint((colors + 1) * 127.5), 0, 255)
    np.testing.assert_array_equal(lmap.colors, expected)
    np.testing.assert_array_equal(lmap.colors[0], [255, 0, 128])
    np.testing.assert_array_equal(again.colors, lmap.colors)


def test_a_legacy_non_zip_fused_file_is_detected(tmp_path):
    """A fused file saved in torch's legacy format (``_use_new_zipfile_serialization=False``,
    as older torch writes it) was taken by ``auto`` for a per-image feature map and
    refused; it is detected as OpenScene's by its pickles' bytes and read the same."""
    s = scannet_scene(tmp_path, n=60, d=8)
    pt = s["pts"][0]
    saved = torch.load(pt, weights_only=True)
    legacy = pt.with_name("scene0011_00_1.pt")
    torch.save(saved, legacy, _use_new_zipfile_serialization=False)
    assert legacy.read_bytes()[:2] != b"PK"  # not a zip archive
    assert registry.create("adapters", "openscene").sniff(legacy)
    assert detect_adapter(legacy) == "openscene"
    lmap, zipped = read_map(legacy), read_map(pt)
    np.testing.assert_array_equal(read_all(lmap), read_all(zipped))
    np.testing.assert_array_equal(lmap.positions, zipped.positions)
    # a legacy bare tensor is still a frame, and a legacy dict of other keys no fused file
    frame = tmp_path / "saved-feat" / "frame0.pt"
    frame.parent.mkdir()
    torch.save(torch.zeros(4, 5, 8), frame, _use_new_zipfile_serialization=False)
    assert detect_adapter(frame) == "image-features"
    other = tmp_path / "other_0.pt"
    torch.save({"weights": torch.zeros(3)}, other, _use_new_zipfile_serialization=False)
    assert not registry.create("adapters", "openscene").sniff(other)


def test_refusals_give_the_safe_fix_never_torch_advice(tmp_path):
    """torch's weights_only text (ANSI codes, 'Re-running torch.load with weights_only set
    to False') never reaches the user: the refusal names the file, what it references
    and how to re-save it safely, for the fused .pt and for the scene's .pth."""
    s = scannet_scene(tmp_path, n=40, d=8)
    pt, marker, good_pt = s["pts"][0], tmp_path / "pwned", s["pts"][0].read_bytes()
    torch.save({"feat": torch.zeros(3, 8), "mask_full": Payload(marker)}, pt)
    with pytest.raises(MapFormatError) as info:
        read_map(pt, "openscene")
    msg = str(info.value)
    assert msg.startswith(f"{pt}: refused: the fused-feature file holds objects other than")
    assert "system" in msg and "torch.save({'feat': feat.half(), 'mask_full'" in msg
    pt.write_bytes(good_pt)
    torch.save((s["coords"], Payload(marker), s["labels"]), s["pth"])
    with pytest.raises(MapFormatError) as info:
        read_map(pt, "openscene")
    pth_msg = str(info.value)
    assert pth_msg.startswith(f"{s['pth']}: refused") and "points=PATH" in pth_msg
    assert "torch.save((coords, colors, labels), PATH)" in pth_msg
    for said in (msg, pth_msg):
        assert "\x1b[" not in said and "weights_only=False" not in said
        assert "add_safe_globals" not in said and "trust" not in said
    assert not marker.exists()


def test_unreadable_numpy_features_or_points_say_how_to_fix_them(tmp_path):
    """A ``.npy`` of features or points that numpy refuses said only 'not a readable .npy
    array (...)': a cut-short file is to be copied again, an array of Python objects
    re-saved as numbers."""
    s = scannet_scene(tmp_path, n=50, d=8)
    feats = np.random.default_rng(1).normal(size=(50, 8)).astype(np.float32)
    path = tmp_path / "openseg" / "scene0011_00_openscene_feat_ensemble.npy"
    np.save(path, feats)
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) // 2])  # an interrupted copy
    with pytest.raises(MapFormatError, match="truncated .*copy or extract that file again"):
        read_map(path, "openscene")
    np.save(path, np.array([{"a": 1}] * 50, dtype=object), allow_pickle=True)
    with pytest.raises(MapFormatError, match=r"Python objects.*np\.asarray\(features"):
        read_map(path, "openscene")
    np.save(path, feats)
    xyz = tmp_path / "xyz.npy"
    np.save(xyz, s["coords"])
    xyz.write_bytes(xyz.read_bytes()[:100])
    with pytest.raises(MapFormatError, match="copy or extract that points file again"):
        read_map(path, "openscene", points=str(xyz))
