"""Per-image feature maps: layouts, frames, colours, per-image masks."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from _cf_writers import contrast_config, save_feat_pt, save_png, text_table, tree_hash

from quash_plugins import Quash
from quash_plugins.adapters import detect_adapter, masks_per_frame, pixel_coordinates, read_map
from quash_plugins.cli.main import main
from quash_plugins.core import registry


def cf_frame(vecs, h, w, chair_box, seed):
    """ConceptFusion frame: unit pixels ('other' background, 'chair' in a box), zero strip."""
    rng = np.random.default_rng(seed)
    feat = np.tile(vecs["other"], (h, w, 1)) + 0.05 * rng.normal(size=(h, w, len(vecs["other"])))
    y0, y1, x0, x1 = chair_box
    feat[y0:y1, x0:x1] = vecs["chair"]
    feat /= np.linalg.norm(feat, axis=-1, keepdims=True)
    feat[:, 0] = 0  # pixels no mask covered
    return feat.astype(np.float16)


@pytest.fixture
def cf_feat(tmp_path):
    table, vecs = text_table(tmp_path, 16)
    folder = tmp_path / "saved-feat"
    boxes = {"frame000000": (1, 3, 2, 5), "frame000020": (0, 2, 4, 7), "frame000100": (3, 5, 0, 3)}
    frames = {}
    for i, (stem, box) in enumerate(boxes.items()):
        frames[stem] = cf_frame(vecs, 5, 7, box, i)
        save_feat_pt(folder, stem, frames[stem])
        # Images at twice the feature resolution, as ConceptFusion extracts at reduced size.
        rgb = np.zeros((10, 14, 3), np.uint8)
        rgb[..., 0] = 40 * (i + 1)
        save_png(folder / f"{stem}.png", rgb)
    return tmp_path, folder, frames, boxes, table, vecs


def test_frames_rows_and_colors(cf_feat):
    _, folder, frames, _, _, _ = cf_feat
    assert detect_adapter(folder) == "image-features"
    lmap = registry.create("adapters", "image-features").read(folder)
    assert lmap.kind == "pixels" and lmap.positions is None
    assert [f.frame_id for f in lmap.frames] == ["frame000000", "frame000020", "frame000100"]
    assert [f.offset for f in lmap.frames] == [0, 35, 70] and lmap.n == 105
    assert all(f.image_path and f.image_path.endswith(".png") for f in lmap.frames)
    # float16 stays float16 and is never one big ndarray.
    assert lmap.embeddings.dtype == np.float16 and not isinstance(lmap.embeddings, np.ndarray)
    stacked = np.concatenate([f.reshape(-1, 16) for f in frames.values()])
    np.testing.assert_array_equal(lmap.embeddings[30:80], stacked[30:80])
    np.testing.assert_array_equal(np.asarray(lmap.embeddings), stacked)
    # Colours: images resized to the feature resolution (uniform colour per frame).
    assert lmap.colors.shape == (105, 3)
    assert (lmap.colors[:35, 0] == 40).all() and (lmap.colors[70:, 0] == 120).all()


def test_masks_per_frame_recovered_end_to_end(cf_feat):
    tmp, folder, frames, boxes, table, vecs = cf_feat
    quash = Quash.from_config(contrast_config(tmp, table), cache=False)
    lmap = quash.read_map(folder)
    result = quash.query(lmap, "chair")
    per_image = masks_per_frame(lmap, result.mask)
    assert set(per_image) == set(boxes)
    for stem, (y0, y1, x0, x1) in boxes.items():
        expected = np.zeros((5, 7), bool)
        expected[y0:y1, x0:x1] = True
        expected[:, 0] = False  # zero pixels never match
        np.testing.assert_array_equal(per_image[stem], expected)
    coords = pixel_coordinates(lmap, np.flatnonzero(result.mask))
    for x, y, f in coords:
        assert per_image[lmap.frames[f].frame_id][y, x]


def test_image_paths_hold_from_any_folder(cf_feat, monkeypatch):
    """A map read by a relative path records its images absolutely: a zarr store keeps
    the frames, and its image paths must not depend on the folder it was written from."""
    tmp, folder, _, boxes, _, _ = cf_feat
    monkeypatch.chdir(tmp)
    lmap = read_map("saved-feat")
    monkeypatch.chdir(folder)
    assert [f.frame_id for f in lmap.frames] == list(boxes)
    for f in lmap.frames:
        path = Path(f.image_path)
        assert path.is_absolute() and path.is_file()
        assert path.samefile(folder / f"{f.frame_id}.png")


def test_pickled_pixel_map_carries_no_loaded_frames(cf_feat):
    """A Dask task holding the embeddings (``--backend dask``) must not carry the frames
    already loaded on the client: the frames of a real map are 100s of MB each."""
    cloudpickle = pytest.importorskip("cloudpickle")
    lmap = read_map(cf_feat[1])
    cold = len(cloudpickle.dumps(lmap.embeddings))
    everything = np.asarray(lmap.embeddings)  # every frame now loaded (cached)
    warm = cloudpickle.dumps(lmap.embeddings)
    assert len(warm) < cold + 256 < cold + everything.nbytes // 4
    again = cloudpickle.loads(warm)
    np.testing.assert_array_equal(np.asarray(again), everything)
    np.testing.assert_array_equal(again[40:50], everything[40:50])


def test_lseg_layout_and_npy(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(1, 6, 3, 4)).astype(np.float32)  # (1, D, h, w)
    b = rng.normal(size=(3, 4, 6)).astype(np.float32)  # (H, W, D) as .npy
    save_feat_pt(tmp_path / "feat", "f1", a)
    np.save(tmp_path / "feat" / "f2.npy", b)
    lmap = read_map(tmp_path / "feat", "image-features")
    assert lmap.n == 24 and lmap.dim == 6 and lmap.colors is None
    expected = np.concatenate([a[0].transpose(1, 2, 0).reshape(-1, 6), b.reshape(-1, 6)])
    np.testing.assert_array_equal(np.asarray(lmap.embeddings), expected)
    # Item offset + y*W + x is pixel (x, y): check one LSeg pixel directly.
    assert np.array_equal(lmap.embeddings[1 * 4 + 2], a[0, :, 1, 2])


def test_one_npy_frame_is_detected_by_its_shape(tmp_path):
    """A single <stem>.npy frame is read with --adapter auto, as a single .pt is; other
    .npy files (an (N, D) table, an OpenLex3D embeddings.npy) are not taken for frames."""
    rng = np.random.default_rng(0)
    np.save(tmp_path / "img_0.npy", rng.normal(size=(1, 6, 3, 4)).astype(np.float32))
    np.save(tmp_path / "frame1.npy", rng.normal(size=(3, 4, 6)).astype(np.float16))
    np.save(tmp_path / "table.npy", rng.normal(size=(12, 6)).astype(np.float32))
    assert detect_adapter(tmp_path / "img_0.npy") == "image-features"
    assert detect_adapter(tmp_path / "frame1.npy") == "image-features"
    assert read_map(tmp_path / "img_0.npy").frames[0].frame_id == "img_0"
    from quash_plugins.core.errors import MapFormatError

    with pytest.raises(MapFormatError, match="No adapter recognises"):
        detect_adapter(tmp_path / "table.npy")


def test_images_in_sibling_folder_and_option(tmp_path):
    feat = np.ones((2, 3, 4), np.float16)
    save_feat_pt(tmp_path / "saved-feat", "frame7", feat)
    save_png(tmp_path / "rgb" / "frame7.jpg", np.full((2, 3, 3), 200, np.uint8))
    lmap = read_map(tmp_path / "saved-feat", "image-features")
    assert lmap.frames[0].image_path.endswith("rgb/frame7.jpg")
    assert abs(int(lmap.colors[0, 0]) - 200) <= 3  # jpeg
    other = tmp_path / "elsewhere"
    save_png(other / "frame7.png", np.full((2, 3, 3), 9, np.uint8))
    lmap = registry.create("adapters", "image-features", images=str(other)).read(
        tmp_path / "saved-feat"
    )
    assert (lmap.colors == 9).all()
    lmap = registry.create("adapters", "image-features", colors=False).read(tmp_path / "saved-feat")
    assert lmap.colors is None


def test_natural_frame_order(tmp_path):
    for i in (10, 2, 1):
        save_feat_pt(tmp_path, f"frame{i}", np.full((1, 2, 3), i, np.float16))
    lmap = read_map(tmp_path, "image-features")
    assert [f.frame_id for f in lmap.frames] == ["frame1", "frame2", "frame10"]


def test_masks_per_frame_needs_frames_and_right_length(cf_feat):
    from quash_plugins.core.errors import QuashError
    from quash_plugins.core.types import LatentMap

    with pytest.raises(QuashError, match="no frames"):
        masks_per_frame(LatentMap(np.ones((3, 2), np.float32)), np.ones(3, bool))
    lmap = read_map(cf_feat[1])
    with pytest.raises(QuashError, match="shape"):
        masks_per_frame(lmap, np.ones(3, bool))


def test_cli_query_auto_input_unchanged(cf_feat):
    tmp, folder, _, boxes, table, _ = cf_feat
    before = tree_hash(folder)
    out = tmp / "r.npz"
    cfg = contrast_config(tmp, table)
    assert (
        main(
            [
                "-q",
                "query",
                str(folder),
                "chair",
                "-c",
                str(cfg),
                "--adapter",
                "auto",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    with np.load(out) as z:
        assert z["masks"].shape == (1, 105)
        expected = sum((y1 - y0) * (x1 - x0 - (x0 == 0)) for y0, y1, x0, x1 in boxes.values())
        assert z["masks"].sum() == expected
        mask = z["masks"][0]
    assert tree_hash(folder) == before
    # The result file alone cuts its masks into per-image masks, as the map does.
    from quash_plugins.adapters import frames_from_npz

    _cuts_as_the_map_does(frames_from_npz(out), read_map(folder), mask, boxes)


def _cuts_as_the_map_does(frames, lmap, mask, boxes) -> None:
    """Frames read back from a result file are the map's (less image paths), and cut
    ``mask`` into the same per-image masks as the map, one per frame in order."""
    assert frames == [replace(f, image_path=None) for f in lmap.frames]
    from_file = masks_per_frame(frames, mask)
    from_map = masks_per_frame(lmap, mask)
    assert list(from_file) == list(boxes) == list(from_map)
    for stem in boxes:
        np.testing.assert_array_equal(from_file[stem], from_map[stem])


@pytest.mark.parametrize("steps", ["", "presence: {min_component: 2}\n"])
def test_zarr_result_keeps_the_frames(cf_feat, steps):
    """``--out RESULT.zarr`` stores the frame layout as the NPZ result does (attributes
    frame_ids, frame_hw, frame_offsets): the store alone gives per-image masks. Both
    writers: the fully lazy one, and the one that answers queries with presence."""
    pytest.importorskip("zarr")
    pytest.importorskip("dask")
    import zarr

    from quash_plugins.adapters import frames_from_zarr

    tmp, folder, _, boxes, table, _ = cf_feat
    cfg = contrast_config(tmp, table)
    cfg.write_text(cfg.read_text() + steps)
    out = tmp / "r.zarr"
    args = ["-q", "query", str(folder), "chair", "-c", str(cfg), "--out", str(out)]
    assert main(args) == 0
    store = zarr.open_group(str(out), mode="r")
    mask = store["masks"][0]
    assert mask.shape == (105,) and mask.any()
    assert store.attrs["frame_ids"] == list(boxes)
    assert store.attrs["frame_hw"] == [[5, 7]] * 3
    assert store.attrs["frame_offsets"] == [0, 35, 70]
    _cuts_as_the_map_does(frames_from_zarr(out), read_map(folder), mask, boxes)
    with np.load(_npz_result(tmp, folder, cfg)) as z:  # the same masks as --out RESULT.npz
        np.testing.assert_array_equal(z["masks"][0], mask)


def _npz_result(tmp, folder, cfg):
    out = tmp / "r.npz"
    assert main(["-q", "query", str(folder), "chair", "-c", str(cfg), "--out", str(out)]) == 0
    return out


def test_frames_from_zarr_of_maps_and_stores_without_frames(cf_feat, tmp_path):
    pytest.importorskip("zarr")
    from quash_plugins.adapters import frames_from_zarr, write_zarr_map

    _, folder, _, _, _, _ = cf_feat
    lmap = read_map(folder)
    store = write_zarr_map(lmap, tmp_path / "map.zarr")
    assert frames_from_zarr(store) == lmap.frames  # a zarr map keeps the image paths
    voxels = write_zarr_map(
        registry.create("adapters", "npz").read(
            registry.create("adapters", "npz").write_example(tmp_path)
        ),
        tmp_path / "voxels.zarr",
    )
    assert frames_from_zarr(voxels) is None


def test_docs_adapters_python_blocks_run(cf_feat, capsys, monkeypatch):
    import re
    from pathlib import Path

    doc = Path(__file__).resolve().parents[2] / "docs" / "adapters.md"
    # The OpenLex3D section's block reads query results: test_openlex3d_export runs it.
    text = re.sub(r"### Writing OpenLex3D's layout.*?### ", "### ", doc.read_text(), flags=re.S)
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.S)
    assert blocks
    # The per-image block reads chair.npz, as the command above it writes it.
    tmp, folder, _, boxes, table, _ = cf_feat
    monkeypatch.chdir(tmp)
    cfg = contrast_config(tmp, table)
    assert main(["-q", "query", str(folder), "chair", "-c", str(cfg), "--out", "chair.npz"]) == 0
    for block in blocks:
        exec(compile(block, str(doc), "exec"), {"__name__": "adapters_doc"})
    out = capsys.readouterr().out
    assert "(6, 8)" in out
    assert all(f"'{stem}': ((5, 7), " in out for stem in boxes), out


def test_a_pt_from_a_newer_torch_says_so_and_how_to_read_it(tmp_path):
    """A frame saved by a newer torch (its archive's version record above what this
    torch reads) is refused naming the file, this torch's version, and the fixes."""
    import zipfile

    from quash_plugins.core.errors import MapFormatError

    torch = pytest.importorskip("torch")
    old = tmp_path / "old.pt"
    torch.save(torch.zeros(2, 3, 4, dtype=torch.float16), old)
    feat = tmp_path / "feat"
    feat.mkdir()
    with zipfile.ZipFile(old) as zin, zipfile.ZipFile(feat / "frame0.pt", "w") as zout:
        for info in zin.infolist():
            data = zin.read(info)
            zout.writestr(info, b"99\n" if info.filename.endswith("/version") else data)
    with pytest.raises(MapFormatError) as info:
        read_map(feat, adapter="image-features")
    msg = str(info.value)
    assert "frame0.pt" in msg and "newer torch" in msg and torch.__version__ in msg
    assert "np.save('frame0.npy'" in msg


def test_camera_files_beside_the_frames_are_skipped_and_said(tmp_path, caplog):
    """A feature folder often holds the run's camera files too (poses.npy, intrinsics.npy,
    a (4, 4) pose, an (N, 4, 4) trajectory under another name): the adapter read them as
    frames and failed on intrinsics.npy. They are left out, by name or by shape, with an
    INFO line naming each; the frames read as before."""
    import logging

    rng = np.random.default_rng(0)
    folder = tmp_path / "saved-feat"
    folder.mkdir()
    frames = [rng.normal(size=(4, 5, 16)).astype(np.float32) for _ in range(3)]
    for i, f in enumerate(frames):
        np.save(folder / f"frame{i}.npy", f)
    save_feat_pt(folder, "frame3", rng.normal(size=(1, 16, 2, 3)).astype(np.float32))
    np.save(folder / "poses.npy", np.tile(np.eye(4), (5, 1, 1)))  # (5, 4, 4): frame-shaped
    np.save(folder / "intrinsics.npy", np.eye(3))
    np.save(folder / "first_pose.npy", np.eye(4))  # plainly no frame by its shape
    np.save(folder / "cams.npy", np.zeros((5, 4, 4)))  # D 4, not the frames' 16
    assert detect_adapter(folder) == "image-features"
    with caplog.at_level(logging.INFO, logger="quash_plugins"):
        lmap = read_map(folder)
    assert [f.frame_id for f in lmap.frames] == ["frame0", "frame1", "frame2", "frame3"]
    assert lmap.n == 3 * 20 + 6 and lmap.dim == 16
    np.testing.assert_array_equal(
        np.asarray(lmap.embeddings[:60]), np.concatenate([f.reshape(-1, 16) for f in frames])
    )
    said = " ".join(r.getMessage() for r in caplog.records if "skipped" in r.getMessage())
    for name in ("poses.npy", "intrinsics.npy", "first_pose.npy (shape (4, 4)", "cams.npy"):
        assert name in said, said
    assert "frame0" not in said and len(lmap.source["skipped"]) == 4
    # a folder of camera files only is no feature folder
    cams = tmp_path / "cams"
    cams.mkdir()
    np.save(cams / "poses.npy", np.tile(np.eye(4), (4, 1, 1)))
    assert not registry.create("adapters", "image-features").sniff(cams)


def test_a_frame_of_another_model_is_still_refused(tmp_path):
    """Skipping never hides two models' frames: with no D shared by more frames, the
    error names the file, and for a .npy says to move it out if it is no frame."""
    from quash_plugins.core.errors import MapFormatError

    np.save(tmp_path / "a.npy", np.ones((2, 3, 16), np.float32))
    np.save(tmp_path / "b.npy", np.ones((2, 3, 8), np.float32))
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path, "image-features")
    msg = str(info.value)
    assert "b.npy: feature dimension 8" in msg and "move it out of the folder" in msg


def _no_torch_advice(msg):
    """What a refusal must never pass on from torch: its terminal colours, its advice to
    load with weights_only=False (which runs the file's code), its allow-list advice."""
    assert "\x1b[" not in msg, repr(msg)
    assert "weights_only=False" not in msg and "weights_only` set to `False" not in msg
    assert "add_safe_globals" not in msg and "trust" not in msg


@pytest.mark.parametrize(
    ("saved", "holds"),
    [
        ("numpy", "multiarray._reconstruct"),  # torch.save of a numpy array
        ("object", "it references"),  # a dict holding an arbitrary object
    ],
)
def test_a_frame_torch_refuses_to_load_is_refused_with_the_safe_fix(tmp_path, saved, holds):
    """A .pt that torch.load(weights_only=True) refuses was shown with torch's raw text
    (ANSI codes, advice to load it with weights_only=False): it is refused naming the
    file, what it holds, and the safe fix (re-save as a bare tensor or as numpy)."""
    from quash_plugins.core.errors import MapFormatError

    torch = pytest.importorskip("torch")
    frame = np.ones((2, 3, 4), np.float32)
    obj = frame if saved == "numpy" else {"feat": torch.from_numpy(frame), "meta": object()}
    torch.save(obj, tmp_path / "f0.pt")
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path, adapter="image-features")
    msg = str(info.value)
    assert msg.startswith(f"{tmp_path / 'f0.pt'}: refused") and holds in msg
    assert "objects other than tensors and plain containers" in msg
    assert "torch.save(torch.as_tensor(features), 'f0.pt')" in msg and "np.save('f0.npy'" in msg
    _no_torch_advice(msg)
    # the fix it gives works
    np.save(tmp_path / "f0.npy", frame)
    (tmp_path / "f0.pt").unlink()
    assert read_map(tmp_path, adapter="image-features").n == 6


def test_torch_text_passed_through_loses_its_colour_codes(tmp_path, monkeypatch):
    """Any other load error of torch's is shown by its first line, without ANSI codes."""
    from quash_plugins.core.errors import MapFormatError

    torch = pytest.importorskip("torch")
    torch.save(torch.zeros(2, 3, 4), tmp_path / "f0.pt")

    def failing_load(*args, **kwargs):
        raise RuntimeError("\x1b[1mstorage\x1b[0m \x1b[31mis damaged\x1b[0m\nmore text")

    monkeypatch.setattr(torch, "load", failing_load)
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path, adapter="image-features")
    msg = str(info.value)
    assert "f0.pt: not a readable tensor file (storage is damaged)" in msg
    _no_torch_advice(msg)


def test_reading_the_frames_and_their_images_shows_progress(tmp_path, caplog, monkeypatch):
    """Reading a feature folder opened every frame and decoded every RGB image before
    'read pixels map' with nothing said (400 frames with 640 x 480 images: 7 s here);
    both steps now report progress, as a query's pass does."""
    import logging

    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    monkeypatch.setattr("quash_plugins.core.progress.QUIET", False)
    for stem in ("frame0", "frame1", "frame2"):
        save_feat_pt(tmp_path / "saved-feat", stem, np.ones((2, 3, 4), np.float16))
        save_png(tmp_path / "rgb" / f"{stem}.png", np.zeros((4, 6, 3), np.uint8))
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    assert read_map(tmp_path / "saved-feat").colors is not None
    assert "reading 3 feature files: 3/3 (100%" in caplog.text
    assert "reading 3 RGB images: 3/3 (100%" in caplog.text


def test_a_map_whose_images_are_not_found_says_so(tmp_path, caplog):
    """Frames whose RGB images lie elsewhere (a dataset's results/ folder) were read with
    no colours and nothing said; an INFO line now names where images were looked for
    and the option that names their folder."""
    import logging

    save_feat_pt(tmp_path / "saved-feat", "frame0", np.ones((2, 3, 4), np.float16))
    caplog.set_level(logging.INFO, logger="quash_plugins.adapters")
    assert read_map(tmp_path / "saved-feat").colors is None
    assert "no RGB image named after a frame (frame0.png, .jpg)" in caplog.text
    assert "-o images=DIR" in caplog.text
    caplog.clear()
    assert read_map(tmp_path / "saved-feat", colors=False).colors is None  # none asked for
    assert "no RGB image" not in caplog.text
