"""Malformed maps raise MapFormatError naming the file and the field, and are never written."""

from __future__ import annotations

import gzip
import pickle

import h5py
import numpy as np
import pytest
from _cf_writers import cf_arrays, save_feat_pt, save_openlex3d, save_pointclouds, tree_hash

from quash_plugins.adapters import read_map, write_openlex3d_map
from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError


def _cf(tmp_path, **changes):
    arrays = cf_arrays(n=20, d=6)
    for k, v in changes.items():
        if v is None:
            arrays.pop(k)
        else:
            arrays[k] = v
    return save_pointclouds(tmp_path / "m", **arrays).parent


def _check(source, *needles, adapter="auto", **options):
    before = tree_hash(source)
    with pytest.raises(MapFormatError) as info:
        lmap = read_map(source, adapter, **options)
        # NaN/Inf in large lazy maps is found when rows are read.
        for _ in lmap.iter_chunks(7):
            pass
    msg = str(info.value)
    for needle in needles:
        assert needle in msg, msg
    assert tree_hash(source) == before
    return msg


# ----------------------------------------------------------------- conceptfusion
def test_cf_missing_embeddings_file(tmp_path):
    _check(
        _cf(tmp_path, pc_embeddings=None),
        "pc_embeddings.h5",
        "missing file",
        adapter="conceptfusion",
    )


def test_cf_missing_dataset(tmp_path):
    root = _cf(tmp_path)
    path = root / "pointclouds" / "pc_embeddings.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("embeddings", data=np.ones((20, 6), np.float32))
    _check(root, "pc_embeddings.h5", "'pc_embeddings'", "missing dataset")


def test_cf_mismatched_rows(tmp_path):
    root = _cf(tmp_path, pc_embeddings=np.ones((19, 6), np.float16))
    _check(root, "pc_embeddings.h5", "19 rows", "20 points")


def test_cf_mismatched_colors(tmp_path):
    _check(_cf(tmp_path, pc_colors=np.ones((5, 3), np.float32)), "pc_colors.h5", "'colors'")


@pytest.mark.parametrize(
    ("key", "field", "shape"),
    [
        ("pc_colors", "'colors'", (25, 3)),
        ("pc_embeddings", "'embeddings'", (19, 6)),
        ("pc_features", "'pc_features'", (21, 3)),
        ("pc_confidences", "'pc_confidences'", (7, 1)),
    ],
)
def test_cf_per_point_rows_not_the_points_name_both_counts_and_the_fix(tmp_path, key, field, shape):
    """A per-point file with another row count than pc_points.h5 (from another map, or a
    save cut short) said 'row counts must match' (or for colours 'must be (N, 3)') with
    no fix."""
    root = _cf(tmp_path, **{key: np.ones(shape, np.float32)})
    points = root / "pointclouds" / "pc_points.h5"
    _check(
        root,
        f"{key}.h5",
        field,
        f"{shape[0]} rows",
        f"{points} has 20 points",
        "from another map",
        "re-save it",
    )


@pytest.mark.parametrize("shape", [(20,), (20, 6, 1)])
def test_cf_wrong_rank_embeddings(tmp_path, shape):
    _check(
        _cf(tmp_path, pc_embeddings=np.ones(shape, np.float32)),
        "pc_embeddings.h5",
        "'embeddings'",
        "2-D",
    )


def test_cf_wrong_rank_points(tmp_path):
    _check(_cf(tmp_path, pc_points=np.ones((20, 2), np.float32)), "pc_points.h5", "'positions'")


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_cf_nan_inf_embeddings(tmp_path, bad):
    emb = cf_arrays(n=20, d=6)["pc_embeddings"]
    emb[13, 2] = bad
    _check(
        _cf(tmp_path, pc_embeddings=emb), "pc_embeddings.h5", "'embeddings'", "NaN or Inf", "row 13"
    )


def test_cf_nan_found_at_query_time_when_not_scanned(tmp_path):
    emb = cf_arrays(n=20, d=6)["pc_embeddings"]
    emb[5, 0] = np.nan
    root = _cf(tmp_path, pc_embeddings=emb)
    _check(root, "'embeddings'", "NaN or Inf", "row 5", check_finite=False)


def test_cf_nan_points(tmp_path):
    pts = cf_arrays(n=20, d=6)["pc_points"]
    pts[4, 1] = np.nan
    _check(_cf(tmp_path, pc_points=pts), "pc_points.h5", "'positions'", "NaN")


def test_cf_empty_cloud_is_an_empty_map(tmp_path):
    """gradslam's save_to_h5 writes every attribute of a 0-point cloud: read, not refused."""
    root = _cf(
        tmp_path,
        pc_points=np.zeros((0, 3), np.float32),
        pc_embeddings=np.zeros((0, 6), np.float16),
        pc_colors=np.zeros((0, 3), np.float32),
        pc_features=np.zeros((0, 3), np.float32),
        pc_confidences=np.zeros((0, 1), np.float32),
    )
    lmap = read_map(root)
    assert (lmap.n, lmap.dim, lmap.dtype) == (0, 6, np.float16)
    assert lmap.positions.shape == (0, 3) and lmap.colors.shape == (0, 3)


def test_cf_no_feature_dimension(tmp_path):
    root = _cf(tmp_path, pc_embeddings=np.zeros((20, 0), np.float16))
    _check(root, "pc_embeddings.h5", "no feature dimension")


def test_cf_truncated_hdf5(tmp_path):
    root = _cf(tmp_path, pc_embeddings=np.ones((2000, 64), np.float32))
    path = root / "pointclouds" / "pc_embeddings.h5"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    _check(root, "pc_embeddings.h5", "truncated")


def test_cf_garbage_file(tmp_path):
    root = _cf(tmp_path)
    (root / "pointclouds" / "pc_points.h5").write_bytes(b"not hdf5 at all")
    _check(root, "pc_points.h5", "HDF5")


# ----------------------------------------------------------------- image features
def test_feat_wrong_rank(tmp_path):
    save_feat_pt(tmp_path, "f0", np.ones((4, 5), np.float16))
    _check(tmp_path, "f0.pt", "'embeddings'", "rank 2", adapter="image-features")


def test_feat_mismatched_dims(tmp_path):
    save_feat_pt(tmp_path, "f0", np.ones((2, 2, 5), np.float16))
    save_feat_pt(tmp_path, "f1", np.ones((2, 2, 6), np.float16))
    _check(tmp_path, "f1.pt", "dimension 6")


def test_feat_nan(tmp_path):
    feat = np.ones((3, 4, 5), np.float16)
    feat[2, 1, 0] = np.inf
    save_feat_pt(tmp_path, "f0", np.ones((3, 4, 5), np.float16))
    save_feat_pt(tmp_path, "f1", feat)
    _check(tmp_path, "f1.pt", "'embeddings'", "NaN or Inf", "x=1, y=2")


def test_feat_empty_dir(tmp_path):
    (tmp_path / "saved-feat").mkdir()
    _check(tmp_path / "saved-feat", "saved-feat", "empty", adapter="image-features")


def test_feat_pickled_object_refused(tmp_path):
    import torch

    torch.save({"feat": torch.ones(2, 2, 3), "meta": object()}, tmp_path / "f0.pt")
    _check(tmp_path, "f0.pt", adapter="image-features")


@pytest.mark.parametrize(
    ("saved", "needles"),
    [
        ({"feat": "tensor", "step": 3}, ("keys: 'feat', 'step'", "torch.save(d['feat'], 'f0.pt')")),
        ({"feat": "tensor", "mask_full": "mask"}, ("--adapter openscene",)),
        (["tensor"], ("holds a list", "torch.save(tensor, PATH)")),
    ],
)
def test_feat_container_of_tensors_says_how_to_save_a_bare_one(tmp_path, saved, needles):
    import torch

    made = {"tensor": torch.ones(2, 2, 3), "mask": torch.ones(4, dtype=torch.bool)}
    if isinstance(saved, dict):
        obj = {k: made.get(v, v) for k, v in saved.items()}
    else:
        obj = [made[v] for v in saved]
    torch.save(obj, tmp_path / "f0.pt")
    _check(tmp_path, "f0.pt", "not a bare tensor", *needles, adapter="image-features")


def test_feat_two_files_of_one_stem_refused(tmp_path):
    """a.pt and a.npy would be two frames with one id: masks_per_frame would drop one."""
    save_feat_pt(tmp_path, "a", np.ones((2, 3, 4), np.float16))
    np.save(tmp_path / "a.npy", np.ones((2, 3, 4), np.float16))
    save_feat_pt(tmp_path, "b", np.ones((2, 3, 4), np.float16))
    _check(tmp_path, "frame 'a'", "a.npy", "a.pt", "Move one", adapter="image-features")


def test_feat_images_folder_given_says_where_features_go(tmp_path):
    from _cf_writers import save_png

    save_png(tmp_path / "rgb" / "frame0.png", np.zeros((4, 4, 3), np.uint8))
    _check(tmp_path / "rgb", "no feature maps", "It holds images", adapter="image-features")


@pytest.mark.parametrize("adapter", ["auto", None])
def test_feat_images_folder_given_to_auto_says_where_features_go(tmp_path, capsys, adapter):
    """The same hint under --adapter auto (the default), which named no adapter before."""
    from _cf_writers import save_png

    from quash_plugins.cli.main import main

    save_png(tmp_path / "rgb" / "frame0.png", np.zeros((4, 4, 3), np.uint8))
    msg = _check(tmp_path / "rgb", "No adapter recognises", "It holds images")
    assert "pass the folder of their feature files" in msg and "-o images=DIR" in msg
    args = ["query", str(tmp_path / "rgb"), "chair"]
    assert main([*args, *(["--adapter", adapter] if adapter else [])]) == 1
    err = capsys.readouterr().err
    assert "It holds images: pass the folder of their feature files" in err
    # a folder of anything else gets no such hint
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("x")
    assert "It holds images" not in _check(tmp_path / "other", "No adapter recognises")


def test_a_faulty_unrecognised_hint_does_not_hide_the_error(tmp_path):
    from quash_plugins.core.interfaces import MapAdapter

    class Faulty(MapAdapter):
        name = "faulty-hint"

        def sniff(self, source):
            return False

        def read(self, source, **options):
            raise AssertionError

        def unrecognised_hint(self, source):
            raise RuntimeError("boom")

    registry.register("adapters", "faulty-hint", Faulty, replace=True)
    try:
        (tmp_path / "x").mkdir()
        _check(tmp_path / "x", "No adapter recognises")
    finally:
        registry.unregister("adapters", "faulty-hint")


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("colors", "maybe"),
        ("colors", 1),
        ("cache_frames", 0),
        ("cache_frames", -3),
        ("cache_frames", 2.5),
        ("cache_frames", True),
    ],
)
def test_feat_options_refused_not_coerced(tmp_path, option, value):
    save_feat_pt(tmp_path, "f0", np.ones((2, 3, 4), np.float16))
    _check(tmp_path, f"option '{option}'", repr(value), adapter="image-features", **{option: value})


def test_feat_images_option_matching_no_frame_refused(tmp_path):
    """images=DIR whose files are not named after the frames would read no colour at all."""
    from _cf_writers import save_png

    save_feat_pt(tmp_path / "saved-feat", "frame0", np.ones((2, 3, 4), np.float16))
    save_png(tmp_path / "photos" / "000000.png", np.zeros((2, 3, 3), np.uint8))
    feat, photos = tmp_path / "saved-feat", str(tmp_path / "photos")
    _check(feat, "images=", "frame0.png", "000000.png", "colors=false", images=photos)
    # colors=false asks for no colours: the unmatched folder is then no error.
    assert read_map(feat, colors=False, images=photos).colors is None


def test_feat_squeezed_lseg_frame_explained_by_the_dimension_error(tmp_path):
    """A (D, h, w) frame (LSeg's (1, D, h, w) without its 1) reads as (H, W, D) with
    D = w: the dimension error says how D was read and how to save the frame."""
    from quash_plugins import Quash
    from quash_plugins.core.errors import DimensionMismatchError

    save_feat_pt(tmp_path / "sq", "f0", np.ones((8, 3, 4), np.float32))  # (D=8, h, w)
    save_feat_pt(tmp_path / "ok", "f0", np.ones((3, 4, 6), np.float32))  # (H, W, D=6)
    quash = Quash.from_config({"encoder": {"name": "table", "table": {"a": [1.0] * 8}}})
    with pytest.raises(DimensionMismatchError) as info:
        quash.query(str(tmp_path / "sq"), "a")
    msg = str(info.value)
    assert "4-dimensional" in msg and "f0.pt, read as (H, W, D) = (8, 3, 4)" in msg
    assert "(1, D, h, w)" in msg
    with pytest.raises(DimensionMismatchError) as info:  # H < D: nothing to explain
        quash.query(str(tmp_path / "ok"), "a")
    assert "6-dimensional" in str(info.value) and "read as" not in str(info.value)


def test_feat_batched_conceptfusion_frame_explained_by_the_dimension_error(tmp_path):
    """A (1, H, W, D) frame (ConceptFusion's features saved without [0]) reads as
    (1, D, h, w) with D = H: the dimension error said only '3-dimensional embeddings ...
    use the text encoder that built the map'; it now says how D was read and the fix."""
    from quash_plugins import Quash
    from quash_plugins.core.errors import DimensionMismatchError

    save_feat_pt(tmp_path / "b", "f0", np.ones((1, 3, 4, 8), np.float16))  # (1, H, W, D=8)
    save_feat_pt(tmp_path / "ok", "f0", np.ones((1, 6, 3, 4), np.float32))  # LSeg: D=6 > w
    quash = Quash.from_config({"encoder": {"name": "table", "table": {"a": [1.0] * 8}}})
    with pytest.raises(DimensionMismatchError) as info:
        quash.query(str(tmp_path / "b"), "a")
    msg = str(info.value)
    assert "3-dimensional" in msg and "f0.pt, read as (1, D, h, w) = (1, 3, 4, 8)" in msg
    assert "save features[0], (H, W, D)" in msg
    with pytest.raises(DimensionMismatchError) as info:  # D > w: nothing to explain
        quash.query(str(tmp_path / "ok"), "a")
    assert "6-dimensional" in str(info.value) and "read as" not in str(info.value)


def test_feat_truncated_pt(tmp_path):
    path = save_feat_pt(tmp_path, "f0", np.ones((8, 8, 16), np.float16))
    path.write_bytes(path.read_bytes()[:200])
    _check(tmp_path, "f0.pt", "not a readable tensor file", adapter="image-features")


# ----------------------------------------------------------------- openlex3d / pickles
def _ol(tmp_path, n=10, table=None, index=None):
    rng = np.random.default_rng(0)
    table = rng.normal(size=(3, 4)).astype(np.float32) if table is None else table
    index = rng.integers(0, 3, size=n) if index is None else index
    return save_openlex3d(tmp_path / "p", rng.normal(size=(n, 3)), None, table, index)


def test_ol_mismatched_rows(tmp_path):
    _check(_ol(tmp_path, index=np.zeros(7, int)), "index.npy", "'index'", "7 entries", "10 points")


def test_ol_index_out_of_range(tmp_path):
    _check(
        _ol(tmp_path, index=np.full(10, 3)), "index.npy", "'index'", "row 3", "(0 to 2)", "arange"
    )
    # np.linspace(0, n, n) is not arange: its last entry is n, one past the table
    dense = np.linspace(0, 10, 10, dtype=np.int32)
    table = np.ones((10, 4), np.float32)
    _check(_ol(tmp_path / "d", table=table, index=dense), "index.npy", "row 10", "np.arange")
    _check(_ol(tmp_path / "m", index=np.full(10, -2)), "index.npy", "holds -2", "-1 for no")


def test_ol_missing_cloud_names_the_accepted_names(tmp_path):
    folder = _ol(tmp_path)
    (folder / "point_cloud.pcd").unlink()
    _check(folder, "point_cloud.pcd", "missing file", "input.ply", adapter="openlex3d")


def test_ol_object_embeddings(tmp_path):
    folder = _ol(tmp_path)
    np.save(folder / "embeddings.npy", np.array([np.ones(4), np.ones(3)], dtype=object))
    _check(folder, "embeddings.npy", "'embeddings'", "Python objects", "numeric array")


def test_ol_wrong_rank(tmp_path):
    _check(
        _ol(tmp_path, table=np.ones((3, 4, 1), np.float32)), "embeddings.npy", "'embeddings'", "2-D"
    )


def test_ol_nan(tmp_path):
    table = np.ones((3, 4), np.float32)
    table[1, 1] = np.nan
    _check(_ol(tmp_path, table=table), "embeddings.npy", "'embeddings'", "NaN")


def test_ol_missing_index(tmp_path):
    folder = _ol(tmp_path)
    (folder / "index.npy").unlink()
    _check(folder, "index.npy", "missing", adapter="openlex3d")


@pytest.mark.parametrize("name", ["map.pkl.gz", "objects.pkl"])
def test_pickle_needs_opt_in(tmp_path, name):
    path = tmp_path / name
    payload = {
        "objects": [
            {"clip_ft": np.ones(4), "pcd_np": np.zeros((2, 3)), "pcd_color_np": np.ones((2, 3))}
        ]
    }
    with (gzip.open if name.endswith(".gz") else open)(path, "wb") as f:
        pickle.dump(payload, f)
    msg = _check(path, name, "allow_pickle")
    assert "pickle" in msg
    lmap = registry.create("adapters", "openlex3d", allow_pickle=True).read(path)
    assert lmap.n == 2 and (lmap.colors == 255).all()


@pytest.mark.parametrize("name", sorted(registry.available("adapters")))
def test_an_unknown_read_option_is_refused_naming_the_options(name, tmp_path):
    """``read(source, **options)`` refuses an option the adapter does not take (a typo
    such as ``pose_typ``) with the adapter's own options, whichever adapter reads it:
    none ignores it, none fails with a bare TypeError."""
    import inspect

    adapter = registry.create("adapters", name)
    source = adapter.write_example(tmp_path)
    takes = [
        p.name
        for p in inspect.signature(type(adapter).__init__).parameters.values()
        if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
    ]
    with pytest.raises(MapFormatError) as err:
        adapter.read(source, bogus_option=1)
    msg = str(err.value)
    assert f"Adapter {name!r}" in msg and "bogus_option" in msg, msg
    assert msg.endswith(f"Options: {', '.join(takes) or '(none)'}."), msg


@pytest.mark.parametrize("name", ["conceptfusion", "openlex3d", "openscene"])
def test_a_finite_check_mb_that_is_no_number_is_named_not_blamed_on_the_file(tmp_path, name):
    """`-o finite_check_mb=abc` was reported as the map's own fault ('cannot read it ...
    ValueError ... The file may be damaged or truncated'), sending the user to copy the
    map again; it is the option, named with a value that works."""
    source = registry.create("adapters", name).write_example(tmp_path)
    msg = _check(
        source,
        "finite_check_mb",
        "'abc'",
        "-o finite_check_mb=512",
        adapter=name,
        finite_check_mb="abc",
    )
    assert "damaged" not in msg and "ValueError" not in msg
    assert read_map(source, name, finite_check_mb="1e3").n > 0  # a number as YAML leaves it


@pytest.mark.parametrize("field", ["pc_points", "pc_colors"])
@pytest.mark.parametrize("dtype", ["S1", "complex64", "bool"])
def test_cf_points_or_colours_that_are_no_numbers_name_the_file_and_field(tmp_path, field, dtype):
    """Text points or colours were reported as a damaged file ('cannot read it ...
    ValueError: could not convert string to float'), naming neither the file nor the
    field; complex and bool ones were read as if they were coordinates and colours."""
    arrays = cf_arrays(n=20, d=6)
    root = _cf(tmp_path, **{field: np.zeros(arrays[field].shape, dtype=dtype)})
    name = "'positions'" if field == "pc_points" else "'colors'"
    msg = _check(root, f"{field}.h5", name, "must hold numbers", dtype)
    assert "damaged" not in msg


@pytest.mark.parametrize("suffix", [".pt", ".npy"])
def test_feat_truncated_frame_says_to_copy_it_again(tmp_path, suffix):
    """A frame cut short (an interrupted copy) was named with no fix: a truncated .npy
    said only 'not a readable .npy array (mmap length is greater than file size)'."""
    frame = np.ones((8, 8, 16), np.float16)
    for stem in ("f0", "f1"):
        if suffix == ".pt":
            save_feat_pt(tmp_path, stem, frame)
        else:
            np.save(tmp_path / f"{stem}.npy", frame)
    path = tmp_path / f"f1{suffix}"  # the last frame of the copy, cut short
    path.write_bytes(path.read_bytes()[:200])
    _check(tmp_path, f"f1{suffix}", "truncated", "copy or extract that frame again")


def test_feat_object_npy_frame_is_not_called_truncated(tmp_path):
    """A .npy of Python objects is no damaged copy: its fix is a numeric re-save."""
    np.save(tmp_path / "f0.npy", np.ones((8, 8, 16), np.float16))
    np.save(tmp_path / "f1.npy", np.array([{"feat": 1}], dtype=object), allow_pickle=True)
    msg = _check(tmp_path, "f1.npy", "Python objects", "np.save('f1.npy'", adapter="image-features")
    assert "truncated" not in msg


def test_feat_folder_of_only_unreadable_frames_names_them_under_auto(tmp_path):
    """A folder whose every frame numpy cannot read is recognised by no adapter: under
    ``--adapter auto`` it said only 'No adapter recognises DIR', naming neither the
    files nor the adapter that says what is wrong with them."""
    from quash_plugins.core.maps import detect_adapter

    for stem in ("f0", "f1"):
        np.save(tmp_path / f"{stem}.npy", np.ones((8, 8, 16), np.float16))
        cut = tmp_path / f"{stem}.npy"
        cut.write_bytes(cut.read_bytes()[:100])
    np.save(tmp_path / "poses.npy", np.eye(4))  # a side file is no frame: not named
    with pytest.raises(MapFormatError) as err:
        detect_adapter(tmp_path)
    msg = str(err.value)
    assert "No adapter recognises" in msg and "f0.npy, f1.npy" in msg
    assert "--adapter image-features" in msg and "poses.npy" not in msg


@pytest.mark.parametrize(
    "name,field", [("embeddings.npy", "'embeddings'"), ("index.npy", "'index'")]
)
def test_ol_truncated_npy_is_called_truncated_not_pickled(tmp_path, name, field):
    """A cut-short embeddings.npy or index.npy (an interrupted copy of an export) was
    reported as holding pickled objects, with the advice to save a numeric array."""
    folder = _ol(tmp_path, table=np.ones((50, 16), np.float32), index=np.arange(10) % 50)
    path = folder / name
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    msg = _check(folder, name, field, "truncated", "copy or export that file again")
    assert "Python objects" not in msg


def test_ol_object_npy_is_still_called_objects(tmp_path):
    folder = _ol(tmp_path)
    np.save(folder / "embeddings.npy", np.array([np.ones(4)] * 3, dtype=object), allow_pickle=True)
    msg = _check(folder, "embeddings.npy", "Python objects", "numeric array")
    assert "np.save('embeddings.npy', np.asarray(embeddings, np.float32))" in msg
    assert "truncated" not in msg


@pytest.mark.parametrize("writer", ["open3d", "quash"])
def test_ol_truncated_binary_cloud_is_refused(tmp_path, writer):
    """open3d reads a cut-short binary point_cloud.pcd as points of whatever memory held
    (open3d's own files) or as 0 points (an export's, then said only as a row-count
    mismatch): it is refused, naming the file and the fix."""
    folder = _ol(tmp_path)
    if writer == "quash":
        lmap = read_map(folder)
        folder = write_openlex3d_map(lmap, tmp_path / "export")
    cloud = folder / "point_cloud.pcd"
    whole = cloud.read_bytes()
    for cut in (len(whole) - 7, len(whole) // 2):  # in the points, in the header
        cloud.write_bytes(whole[:cut])
        _check(folder, "point_cloud.pcd", "'points'", "cut short", "copy or export it again")


def test_vlmaps_2d_npy_files_name_the_fix_as_the_other_adapters_do(tmp_path):
    """The 2023 grid's .npy files had a loader of their own that said only 'truncated?'
    or 'pickled arrays are never loaded'; they now get the fix the other adapters give:
    a new copy of a file cut short, a numeric re-save of an array of Python objects."""
    from _vlmaps_writers import write_vlmaps_2d

    folder, _ = write_vlmaps_2d(tmp_path / "scene", d=8)
    grid = folder / "grid_lseg_1.npy"
    whole = grid.read_bytes()
    grid.write_bytes(whole[: len(whole) // 2])
    msg = _check(folder, "truncated", "copy or create that file again", adapter="vlmaps-2d")
    assert str(grid) in msg and "Python objects" not in msg
    # under auto no adapter takes it: the grid is named with the adapter that says why
    for source in (folder, folder.parent):
        _check(
            source,
            "No adapter recognises",
            f"{grid} is named as VLMaps' 2023 grid",
            "--adapter vlmaps-2d says why",
        )
    grid.write_bytes(whole)
    gt = folder / "grid_1_gt.npy"
    np.save(gt, np.array([{"label": 1}], dtype=object), allow_pickle=True)
    msg = _check(folder, "grid_1_gt.npy", "Python objects", "np.asarray(gt, np.float32)")
    assert "np.save('grid_1_gt.npy'" in msg
    assert "truncated" not in msg
