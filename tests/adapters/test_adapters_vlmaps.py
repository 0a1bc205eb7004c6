"""VLMaps adapters: 3D HDF5 (``vlmaps``), 2023 top-down grids (``vlmaps-2d``), live objects."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import h5py
import numpy as np
import pytest
import yaml
from _vlmaps_writers import mobile_map, sha256, write_vlmaps_2d, write_vlmaps_h5df
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quash_plugins import Quash
from quash_plugins.adapters import detect_adapter, read_map
from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError, QuashError
from quash_plugins.core.h5rows import H5Rows

D = 8
TABLE = {
    w: np.eye(D)[i].tolist() for i, w in enumerate(["chair", "other", "background", "nothing"])
}


def vlmaps(**kw):
    return registry.create("adapters", "vlmaps", **kw)


def unit_rows(x):
    x = np.asarray(x, dtype=np.float64)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


def read_all(lmap):
    return np.concatenate([b for _, _, b in lmap.iter_chunks(7)])


def _centre(k):
    """Centre (in cells) of signed cell offset k under truncation-toward-zero binning."""
    k = np.asarray(k, dtype=np.float64)
    return np.where(k > 0, k + 0.5, np.where(k < 0, k - 0.5, 0.0))


# ---------------------------------------------------------------------- 3D mobile base
def test_mobile_base_rows_positions_colours(tmp_path):
    arrays = mobile_map(n=40, d=D, gs=60)
    path = write_vlmaps_h5df(tmp_path / "vlmap" / "vlmaps.h5df", arrays)
    before = sha256(path)
    lmap = vlmaps(gs=60, cs=0.1, positions="upstream").read(path)
    assert lmap.n == 40 and lmap.dim == D and lmap.kind == "voxels"
    assert isinstance(lmap.embeddings, H5Rows)  # on disk, read block by block
    assert lmap.normalize is True
    row, col, h = (arrays["grid_pos"][:, i].astype(np.float64) for i in range(3))
    expected = np.column_stack([(30 - row) * 0.1, (30 - col) * 0.1, h * 0.1])
    np.testing.assert_allclose(lmap.positions, expected, atol=1e-5)
    np.testing.assert_array_equal(lmap.colors, arrays["grid_rgb"])
    np.testing.assert_array_equal(lmap.grid_index, arrays["grid_pos"])
    assert lmap.voxel_size == pytest.approx(0.1)
    assert lmap.source["pose_type"] == "mobile_base"
    assert sha256(path) == before


def test_mobile_base_gs_from_file_cs_default(tmp_path):
    arrays = mobile_map(n=10, d=D)  # gs = 60 in occupied_ids
    path = write_vlmaps_h5df(tmp_path / "m.h5df", arrays)
    lmap = read_map(path, positions="upstream")  # auto-detected; cs: VLMaps' 0.05
    gp = arrays["grid_pos"].astype(np.float64)
    np.testing.assert_allclose(lmap.positions[:, 0], (30 - gp[:, 0]) * 0.05, atol=1e-5)
    np.testing.assert_allclose(lmap.positions[:, 1], (30 - gp[:, 1]) * 0.05, atol=1e-5)
    np.testing.assert_allclose(lmap.positions[:, 2], gp[:, 2] * 0.05, atol=1e-5)
    assert lmap.voxel_size == pytest.approx(0.05)
    assert lmap.source["gs"] == 60 and lmap.source["gs_from"] == "occupied_ids"


def test_rows_are_normalised_and_zero_rows_stay_zero(tmp_path):
    arrays = mobile_map(n=30, d=D)
    arrays["grid_feat"][[3, 17]] = 0
    path = write_vlmaps_h5df(tmp_path / "m.h5df", arrays)
    got = read_all(vlmaps().read(path))
    np.testing.assert_allclose(got, unit_rows(arrays["grid_feat"]), atol=1e-6)
    assert not got[[3, 17]].any()


def test_float16_stays_float16(tmp_path):
    arrays = mobile_map(n=20, d=D, dtype=np.float16)
    path = write_vlmaps_h5df(tmp_path / "m.h5", arrays)
    lmap = vlmaps().read(path)
    assert lmap.dtype == np.float16 and lmap.embeddings.dtype == np.float16
    assert isinstance(lmap.embeddings, H5Rows)  # on disk, never copied


def test_no_file_is_held_open_while_the_map_lives(tmp_path):
    """The map's rows are read from the file when used; in between, no handle (and no
    HDF5 lock) is held, and the caller may open the file with h5py as VLMaps does."""
    arrays = mobile_map(n=12, d=D)
    path = write_vlmaps_h5df(tmp_path / "m.h5df", arrays)
    lmap = vlmaps().read(path)
    assert not hasattr(lmap, "h5file")
    open_files = h5py.h5f.get_obj_ids(h5py.h5f.OBJ_ALL, h5py.h5f.OBJ_FILE)
    assert not [f for f in open_files if f.name.decode() == str(path)]
    with h5py.File(path, "r") as f:  # the caller's own handle, HDF5's lock and all
        np.testing.assert_array_equal(lmap.embeddings[:2], f["grid_feat"][:2])
    np.testing.assert_array_equal(lmap.embeddings[3:5], arrays["grid_feat"][3:5])
    # a file that changed since the map was read is refused, not read as the map's rows
    write_vlmaps_h5df(path, mobile_map(n=20, d=D, seed=4))
    with pytest.raises(MapFormatError, match="changed on disk since the map was read"):
        lmap.embeddings[:2]


# ---------------------------------------------------------------------- 3D camera base
def camera_arrays():
    arrays = mobile_map(n=25, d=D, gs=20, vh=20, seed=3)
    arrays["grid_rgb"] = arrays["grid_rgb"].astype(np.float32) + 0.4  # averaged colours
    return arrays, {"pcd_min": [-2.5, -0.3, 1.25], "pcd_max": [4.0, 2.0, 6.0], "cs": 0.04}


def test_camera_base_positions_use_stored_pcd_min_and_cs(tmp_path):
    arrays, cam = camera_arrays()
    path = write_vlmaps_h5df(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays, camera=cam)
    lmap = read_map(tmp_path)  # the scene folder resolves to vlmap_cam/vlmaps_cam.h5df
    assert lmap.source["path"] == str(path)
    expected = np.asarray(cam["pcd_min"]) + arrays["grid_pos"].astype(np.float64) * cam["cs"]
    np.testing.assert_allclose(lmap.positions, expected, atol=1e-5)
    assert lmap.voxel_size == pytest.approx(0.04)
    np.testing.assert_array_equal(lmap.colors, np.rint(arrays["grid_rgb"]).astype(np.uint8))


def test_pose_type_can_be_forced(tmp_path):
    arrays, cam = camera_arrays()
    cam_path = write_vlmaps_h5df(tmp_path / "c.h5df", arrays, camera=cam)
    lmap = vlmaps(pose_type="mobile_base", gs=20, cs=0.04, positions="upstream").read(cam_path)
    gp = arrays["grid_pos"].astype(np.float64)
    np.testing.assert_allclose(lmap.positions[:, 0], (10 - gp[:, 0]) * 0.04, atol=1e-5)
    mob = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=5, d=D))
    with pytest.raises(MapFormatError, match=r"m\.h5df.*pcd_min"):
        vlmaps(pose_type="camera_base").read(mob)
    with pytest.raises(QuashError, match="pose_type"):
        vlmaps(pose_type="sideways").read(mob)


# ---------------------------------------------------------------------- labels
@pytest.mark.parametrize("kind", ["txt", "yaml", "json-list", "json-map", "memory", "obj2cls"])
def test_ground_truth_and_label_names(tmp_path, kind):
    names = ["floor", "chair", "table", "sofa"]
    arrays = mobile_map(n=30, d=D)
    sem = np.random.default_rng(1).integers(0, 4, 30).astype(np.int32)
    scene = tmp_path / "scene"
    path = write_vlmaps_h5df(scene / "vlmap" / "vlmaps.h5df", arrays, semantic=sem)
    opt: object
    if kind == "txt":
        opt = tmp_path / "names.txt"
        opt.write_text("\n".join(names) + "\n")
    elif kind == "yaml":
        opt = tmp_path / "names.yaml"
        opt.write_text(yaml.safe_dump(names))
    elif kind == "json-list":
        opt = tmp_path / "names.json"
        opt.write_text(json.dumps(names))
    elif kind == "json-map":
        opt = tmp_path / "names.json"
        opt.write_text(json.dumps({str(i): n for i, n in enumerate(names)}))
    elif kind == "memory":
        opt = dict(enumerate(names))
    else:  # VLMaps' obj2cls_dict.txt beside the scene, found without an option
        lines = [f"{100 + i}: {i}, {n}" for i, n in enumerate(names)]
        (scene / "obj2cls_dict.txt").write_text("\n".join(lines) + "\n")
        opt = None
    lmap = vlmaps(label_names=opt).read(path)
    np.testing.assert_array_equal(lmap.labels, sem)
    assert lmap.label_names == names
    assert lmap.label_index("Chair") == 1


def test_missing_label_ids_are_padded(tmp_path):
    arrays = mobile_map(n=6, d=D)
    sem = np.array([0, 1, 5, 5, -1, 0], dtype=np.int32)
    path = write_vlmaps_h5df(tmp_path / "m.h5df", arrays, semantic=sem)
    lmap = vlmaps(label_names={0: "floor", 5: "chair"}).read(path)
    assert lmap.label_names[0] == "floor" and lmap.label_names[5] == "chair"
    assert lmap.label_names[1] == "label_1"


def test_a_semantic_field_the_file_lacks_is_an_error(tmp_path):
    """A misspelt semantic_field was ignored: the map read without ground truth, and
    quash eval then said the map has no labels, naming neither the option nor the field."""
    arrays = mobile_map(n=6, d=D)
    sem = np.array([0, 1, 1, 0, 1, 0], dtype=np.int32)
    path = write_vlmaps_h5df(tmp_path / "m.h5df", arrays, semantic=sem)
    with pytest.raises(MapFormatError) as err:
        vlmaps(semantic_field="grid_sem").read(path)
    said = str(err.value)
    assert str(path) in said and "semantic_field 'grid_sem'" in said
    assert "grid_semantic" in said  # the file's datasets, the one meant among them
    # the default field may be absent: a map without ground truth reads as before
    unlabelled = write_vlmaps_h5df(tmp_path / "u.h5df", mobile_map(n=6, d=D))
    assert vlmaps().read(unlabelled).labels is None


# ---------------------------------------------------------------------- sniffing
def test_sniff_by_content_not_suffix(tmp_path):
    arrays = mobile_map(n=8, d=D)
    odd = write_vlmaps_h5df(tmp_path / "mapdata.bin", arrays)
    assert detect_adapter(odd) == "vlmaps"
    other = tmp_path / "other.h5df"
    with h5py.File(other, "w") as f:
        f["features"] = np.zeros((3, 2))
    assert not vlmaps().sniff(other)
    assert not vlmaps().sniff(tmp_path / "missing.h5df")
    text = tmp_path / "fake.h5df"
    text.write_text("not hdf5")
    assert not vlmaps().sniff(text)


# ---------------------------------------------------------------------- bad input
def _bad(tmp_path, name, mutate=None, **kw):
    arrays = mobile_map(n=12, d=D)
    if mutate:
        mutate(arrays)
    return write_vlmaps_h5df(tmp_path / name, arrays, **kw)


@pytest.mark.parametrize(
    "name,kw,mutate,field",
    [
        ("nofeat.h5df", {"drop": ("grid_feat",)}, None, "grid_feat"),
        ("nopos.h5df", {"drop": ("grid_pos",)}, None, "grid_pos"),
        ("rows.h5df", {}, lambda a: a.update(grid_pos=a["grid_pos"][:-2]), "grid_pos"),
        (
            "rank.h5df",
            {},
            lambda a: a.update(grid_feat=a["grid_feat"].reshape(12, 2, 4)),
            "grid_feat",
        ),
        ("posrank.h5df", {}, lambda a: a.update(grid_pos=a["grid_pos"][:, :2]), "grid_pos"),
        ("nan.h5df", {}, lambda a: a["grid_feat"].__setitem__((4, 1), np.nan), "grid_feat"),
        ("inf.h5df", {}, lambda a: a["grid_feat"].__setitem__((9, 0), np.inf), "grid_feat"),
        ("rgb.h5df", {}, lambda a: a.update(grid_rgb=a["grid_rgb"][:3]), "grid_rgb"),
        ("sem.h5df", {"semantic": np.zeros(5, np.int32)}, None, "grid_semantic"),
    ],
)
def test_malformed_maps_name_file_and_field(tmp_path, name, kw, mutate, field):
    path = _bad(tmp_path, name, mutate, **kw)
    before = sha256(path)
    with pytest.raises(MapFormatError) as err:
        vlmaps().read(path)
    assert name in str(err.value) and field in str(err.value)
    assert sha256(path) == before


def test_no_feature_dimension(tmp_path):
    arrays = mobile_map(n=5, d=D)
    arrays.update(grid_feat=np.zeros((5, 0), np.float32))
    path = write_vlmaps_h5df(tmp_path / "nodim.h5df", arrays)
    with pytest.raises(MapFormatError, match=r"nodim\.h5df.*grid_feat.*no feature dimension"):
        vlmaps().read(path)


@pytest.mark.parametrize("keep", [0.5, 0.97])
def test_truncated_hdf5(tmp_path, keep):
    arrays = mobile_map(n=400, d=64)
    good = write_vlmaps_h5df(tmp_path / "good.h5df", arrays)
    data = good.read_bytes()
    cut = tmp_path / "cut.h5df"
    cut.write_bytes(data[: int(len(data) * keep)])
    before = sha256(cut)
    with pytest.raises(MapFormatError, match=r"cut\.h5df"):
        vlmaps().read(cut)
    assert sha256(cut) == before


def test_unknown_option_rejected(tmp_path):
    path = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=4, d=D))
    with pytest.raises(QuashError, match="grid_size"):
        vlmaps().read(path, grid_size=3)


# ---------------------------------------------------------------------- end to end
def chair_map(n=60, zero=(5, 6, 7), seed=0):
    """Rows near 'chair' (e0) or near 'other' (e1), arbitrary norms, some zero rows."""
    rng = np.random.default_rng(seed)
    is_chair = rng.random(n) < 0.4
    feat = np.where(is_chair[:, None], np.eye(D)[0], np.eye(D)[1]) + rng.normal(0, 0.05, (n, D))
    feat *= rng.uniform(0.1, 10, (n, 1))
    feat[list(zero)] = 0
    expected = is_chair.copy()
    expected[list(zero)] = False
    return feat.astype(np.float32), expected


def config(tmp_path):
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(TABLE))
    cfg = tmp_path / "quash.yaml"
    cfg.write_text(
        yaml.safe_dump(
            {
                "encoder": {"name": "table", "file": "table.yaml"},
                "classifier": "contrast",
                "cache": False,
            }
        )
    )
    return cfg


def test_quash_end_to_end_zero_rows_never_match(tmp_path):
    feat, expected = chair_map()
    arrays = mobile_map(n=len(feat), d=D)
    arrays["grid_feat"] = feat
    path = write_vlmaps_h5df(tmp_path / "vlmap" / "vlmaps.h5df", arrays)
    before = sha256(path)
    q = Quash.from_config(config(tmp_path))
    res = q.query(path, "chair")
    np.testing.assert_array_equal(res.mask, expected)
    assert not res.mask[[5, 6, 7]].any()
    assert sha256(path) == before


def test_cli_query_auto_adapter(tmp_path):
    from quash_plugins.cli.main import main

    feat, expected = chair_map(seed=2)
    arrays = mobile_map(n=len(feat), d=D)
    arrays["grid_feat"] = feat.astype(np.float16)
    path = write_vlmaps_h5df(tmp_path / "vlmaps-lseg-0.05.h5df", arrays)
    out = tmp_path / "r.npz"
    rc = main(
        [
            "query",
            str(path),
            "chair",
            "-c",
            str(config(tmp_path)),
            "--adapter",
            "auto",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    with np.load(out) as z:
        np.testing.assert_array_equal(z["masks"][0], expected)


# ---------------------------------------------------------------------- 2D grids
def test_vlmaps_2d_observed_cells_positions_colours_labels(tmp_path):
    folder, ref = write_vlmaps_2d(tmp_path / "scene", gs=30)
    before = {p.name: sha256(p) for p in folder.iterdir()}
    lmap = registry.create("adapters", "vlmaps-2d", cs=0.1).read(folder)
    rows, cols = np.nonzero(ref["seen"])  # row-major, as the adapter orders cells
    assert lmap.n == len(rows) and lmap.kind == "voxels" and lmap.normalize
    assert not isinstance(lmap.embeddings, np.ndarray)  # lazy view of the memory map
    # cell centres: VLMaps truncates toward zero when binning, so cell k = 15 - row
    # spans (k, k + 1) * cs for k > 0, (k - 1, k) * cs for k < 0 and (-1, 1) * cs for 0
    expected = np.column_stack(
        [_centre(15 - rows) * 0.1, _centre(15 - cols) * 0.1, np.zeros(len(rows))]
    )
    np.testing.assert_allclose(lmap.positions, expected, atol=1e-5)
    face = registry.create("adapters", "vlmaps-2d", cs=0.1, positions="upstream").read(folder)
    np.testing.assert_allclose(face.positions[:, 0], (15 - rows) * 0.1, atol=1e-5)
    np.testing.assert_array_equal(lmap.colors, ref["color"][rows, cols])
    np.testing.assert_array_equal(lmap.labels, ref["gt"][rows, cols])
    np.testing.assert_array_equal(lmap.grid_index[:, :2], np.column_stack([rows, cols]))
    np.testing.assert_allclose(read_all(lmap), unit_rows(ref["grid"][rows, cols]), atol=1e-6)
    assert lmap.voxel_size == pytest.approx(0.1)
    assert {p.name: sha256(p) for p in folder.iterdir()} == before


def test_vlmaps_2d_path_forms_and_default_cs(tmp_path):
    folder, ref = write_vlmaps_2d(tmp_path / "scene", gs=20)
    for src in (folder / "grid_lseg_1.npy", folder, tmp_path / "scene"):
        assert detect_adapter(src) == "vlmaps-2d"
        lmap = read_map(src)
        r, c = np.nonzero(ref["seen"])
        np.testing.assert_allclose(lmap.positions[:, 0], _centre(10 - r) * 0.05, atol=1e-5)
    full = registry.create("adapters", "vlmaps-2d", keep_empty=True).read(folder)
    assert full.n == 400


def test_vlmaps_2d_bad_input(tmp_path):
    folder, ref = write_vlmaps_2d(tmp_path / "a", gs=10)
    a2d = registry.create("adapters", "vlmaps-2d")
    grid = ref["grid"].copy()
    grid[2, 3, 1] = np.nan
    np.save(folder / "grid_lseg_1.npy", grid)
    with pytest.raises(MapFormatError, match=r"grid_lseg_1\.npy.*NaN.*row 2, col 3"):
        a2d.read(folder)
    np.save(folder / "grid_lseg_1.npy", np.zeros((10, 10, 4), np.float32))
    assert a2d.read(folder).n == 0  # nothing observed: an empty map, not an error
    with pytest.raises(QuashError, match="positions"):
        a2d.read(folder, positions="corner")
    np.save(folder / "grid_lseg_1.npy", np.ones((10, 4), np.float32))
    with pytest.raises(MapFormatError, match=r"\(gs, gs, D\)"):
        a2d.read(folder)
    np.save(folder / "grid_lseg_1.npy", ref["grid"])
    np.save(folder / "color_top_down_1.npy", ref["color"][:5])
    with pytest.raises(MapFormatError, match=r"color_top_down_1\.npy"):
        a2d.read(folder)
    data = (folder / "grid_lseg_1.npy").read_bytes()
    (folder / "grid_lseg_1.npy").write_bytes(data[: len(data) // 2])
    with pytest.raises(MapFormatError, match=r"grid_lseg_1\.npy.*truncated"):
        a2d.read(folder)


# ---------------------------------------------------------------------- live objects
class PoseInfo:
    def __init__(self, pose_type):
        self.pose_type = pose_type


def test_live_vlmap_mobile_and_camera(tmp_path):
    arrays = mobile_map(n=15, d=D)
    live = SimpleNamespace(
        grid_feat=arrays["grid_feat"],
        grid_pos=arrays["grid_pos"],
        grid_rgb=arrays["grid_rgb"],
        gs=60,
        cs=0.1,
        map_config=SimpleNamespace(pose_info=PoseInfo("mobile_base")),
    )
    assert detect_adapter(live) == "vlmaps-live"
    lmap = read_map(live, positions="upstream")
    assert lmap.embeddings is arrays["grid_feat"]  # not copied
    before = arrays["grid_feat"].copy()
    assert np.isfinite(read_all(lmap)).all()
    np.testing.assert_array_equal(arrays["grid_feat"], before)  # read, never normalised in place
    gp = arrays["grid_pos"].astype(np.float64)
    np.testing.assert_allclose(lmap.positions[:, 1], (30 - gp[:, 1]) * 0.1, atol=1e-5)
    np.testing.assert_array_equal(lmap.colors, arrays["grid_rgb"])
    assert lmap.source["up"] == "+z"  # [row, col, height]: z up
    cam = SimpleNamespace(
        grid_feat=arrays["grid_feat"],
        grid_pos=arrays["grid_pos"],
        cs=0.03,
        pcd_min=np.array([1.0, 2.0, 3.0]),
        map_config={"pose_info": {"pose_type": "camera_base"}},
    )
    lmap = read_map(cam)
    np.testing.assert_allclose(lmap.positions, [1, 2, 3] + gp * 0.03, atol=1e-5)
    assert lmap.source["up"] == "+y"  # [row, height, col] in the camera poses' frame
    with pytest.raises(MapFormatError, match="grid_feat"):
        read_map(SimpleNamespace(grid_feat=None, grid_pos=arrays["grid_pos"]), "vlmaps-live")
    with pytest.raises(MapFormatError, match="pcd_min"):
        read_map(
            SimpleNamespace(grid_feat=arrays["grid_feat"], grid_pos=arrays["grid_pos"]),
            "vlmaps-live",
            pose_type="camera_base",
        )


def test_live_adapter_on_a_path_says_it_reads_objects(tmp_path, capsys):
    """`quash query vl chair --adapter vlmaps-live` said "live PosixPath object: attribute
    'grid_feat' is missing or None. Load or build the map first (VLMap.load_map)", advice
    for an object; a path is now refused as a path, with the adapter that reads it."""
    from quash_plugins.cli.main import main

    path = write_vlmaps_h5df(tmp_path / "scene" / "vlmap" / "vlmaps.h5df", mobile_map())
    with pytest.raises(MapFormatError, match=r"reads a VLMap object in Python") as err:
        read_map(path, "vlmaps-live")
    assert "PosixPath" not in str(err.value) and "Load or build" not in str(err.value)
    assert main(["query", str(tmp_path / "scene"), "chair", "--adapter", "vlmaps-live"]) != 0
    msg = " ".join(capsys.readouterr().err.split())
    assert "not a file or folder" in msg and "--adapter vlmaps" in msg


# ---------------------------------------------------------------------- conformance
@pytest.mark.parametrize("name", ["vlmaps", "vlmaps-2d", "vlmaps-live"])
def test_write_example_round_trip(tmp_path, name):
    adapter = registry.create("adapters", name)
    src = adapter.write_example(tmp_path)
    assert adapter.sniff(src)
    assert detect_adapter(src) == name
    lmap = adapter.read(src)
    assert lmap.n > 0 and lmap.positions is not None and np.isfinite(read_all(lmap)).all()


# ---------------------------------------------------------------------- properties
@settings(
    max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    n=st.integers(1, 40),
    d=st.integers(1, 12),
    dtype=st.sampled_from([np.float16, np.float32, np.float64]),
    gs=st.integers(3, 120),
    cs=st.floats(0.01, 0.5),
    seed=st.integers(0, 2**16),
)
def test_property_shapes_and_dtypes(tmp_path_factory, n, d, dtype, gs, cs, seed):
    arrays = mobile_map(n=n, d=d, gs=gs, vh=5, seed=seed, dtype=dtype)
    path = write_vlmaps_h5df(tmp_path_factory.mktemp("p") / "m.h5df", arrays)
    lmap = vlmaps(cs=cs, positions="upstream").read(path)
    assert (lmap.n, lmap.dim, lmap.dtype) == (n, d, np.dtype(dtype))
    gp = arrays["grid_pos"].astype(np.float64)
    np.testing.assert_allclose(lmap.positions[:, 0], (gs / 2 - gp[:, 0]) * cs, rtol=1e-5, atol=1e-4)
    centre = vlmaps(cs=cs).read(path).positions
    np.testing.assert_allclose(centre[:, 1], _centre(gs // 2 - gp[:, 1]) * cs, rtol=1e-5, atol=1e-4)
    got = read_all(lmap)
    ref = unit_rows(arrays["grid_feat"].astype(np.float32))
    np.testing.assert_allclose(got, ref, atol=2e-3 if dtype == np.float16 else 1e-5)


def test_path_objects_accepted(tmp_path):
    path = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=4, d=D))
    assert vlmaps().read(str(path)).n == 4 and vlmaps().read(Path(path)).n == 4


@settings(
    max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    gs=st.integers(1, 24),
    d=st.integers(1, 10),
    dtype=st.sampled_from([np.float16, np.float32]),
    share=st.floats(0.05, 1.0),
    cs=st.floats(0.01, 0.3),
    block_rows=st.integers(1, 9),
    seed=st.integers(0, 2**16),
)
def test_property_2d_grids(tmp_path_factory, gs, d, dtype, share, cs, block_rows, seed):
    rng = np.random.default_rng(seed)
    grid = np.zeros((gs, gs, d), dtype=dtype)
    seen = rng.random((gs, gs)) < share
    seen[0, 0] = True
    grid[seen] = rng.uniform(0.5, 2, (int(seen.sum()), d)).astype(dtype)
    folder = tmp_path_factory.mktemp("g") / "map"
    folder.mkdir()
    np.save(folder / "grid_lseg_1.npy", grid)
    lmap = registry.create("adapters", "vlmaps-2d", cs=cs, block_rows=block_rows).read(folder)
    r, c = np.nonzero(seen)
    assert (lmap.n, lmap.dim, lmap.dtype) == (len(r), d, np.dtype(dtype))
    np.testing.assert_allclose(
        lmap.positions[:, 1], _centre(gs // 2 - c) * cs, rtol=1e-5, atol=1e-4
    )
    np.testing.assert_array_equal(np.asarray(lmap.embeddings), grid[r, c])


def test_2d_embeddings_pickle_by_reference(tmp_path):
    import pickle

    folder, ref = write_vlmaps_2d(tmp_path / "s", gs=40, d=16)
    emb = registry.create("adapters", "vlmaps-2d").read(folder).embeddings
    blob = pickle.dumps(emb)
    assert len(blob) < ref["grid"].nbytes // 10
    np.testing.assert_array_equal(pickle.loads(blob)[:], emb[:])


def test_a_scene_folder_whose_vlmap_folder_has_no_file_says_so(tmp_path, capsys):
    from quash_plugins.cli.main import main
    from quash_plugins.core.errors import MapFormatError

    (tmp_path / "scene" / "vlmap").mkdir(parents=True)
    msg = r"scene/vlmap/ has no vlmaps\.h5df"
    with pytest.raises(MapFormatError, match=msg):
        read_map(tmp_path / "scene", "vlmaps")
    with pytest.raises(MapFormatError, match=msg):
        read_map(tmp_path / "scene")  # auto: the vlmap/ folder says whose it is
    assert main(["convert", str(tmp_path / "scene"), str(tmp_path / "x.npz")]) != 0
    assert "scene/vlmap/ has no vlmaps.h5df" in capsys.readouterr().err
    (tmp_path / "cam" / "vlmap_cam").mkdir(parents=True)
    with pytest.raises(MapFormatError, match=r"cam/vlmap_cam/ has no vlmaps_cam\.h5df"):
        read_map(tmp_path / "cam")


def test_a_missing_map_path_names_the_map_with_a_near_name(tmp_path, monkeypatch):
    """A mistyped map path said only 'Map not found: ... Check the path.' (the config
    loader says 'Did you mean quash.yaml?'). It now names the maps with a near name: the
    camera-base file for the mobile-base path typed, another suffix, a close file name;
    files no adapter reads (a recording beside the map) are not offered."""
    arrays, cam = camera_arrays()
    write_vlmaps_h5df(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays, camera=cam)
    (tmp_path / "vlmap_cam" / "vlmaps.rrd").write_bytes(b"RRF2" + bytes(16))
    monkeypatch.chdir(tmp_path)
    near = "Did you mean vlmap_cam/vlmaps_cam.h5df?"
    for typed in ("vlmap/vlmaps.h5df", "vlmap_cam/vlmaps_cam.h5", "vlmap_cam/vlmaps.h5df"):
        with pytest.raises(MapFormatError) as info:
            read_map(typed)
        assert str(info.value) == f"Map not found: {typed}. {near}"
    with pytest.raises(MapFormatError) as info:
        read_map(tmp_path / "elsewhere" / "scene.npz")
    assert str(info.value).endswith("scene.npz. Check the path.")


def test_a_scene_folder_whose_map_has_a_forks_name_names_that_file(tmp_path, capsys):
    """A fork saves vlmap/vlmaps-lseg-0.05.h5df; the scene folder was refused with 'has
    no vlmaps.h5df ... build or copy the map', as if there were none."""
    from quash_plugins.cli.main import main
    from quash_plugins.core.errors import MapFormatError

    fork = write_vlmaps_h5df(tmp_path / "scene" / "vlmap" / "vlmaps-lseg-0.05.h5df", mobile_map())
    with pytest.raises(MapFormatError, match=r"holds vlmaps-lseg-0\.05\.h5df: pass the map file"):
        read_map(tmp_path / "scene")
    assert main(["query", str(tmp_path / "scene"), "chair"]) != 0
    assert str(fork) in " ".join(capsys.readouterr().err.split())
    assert read_map(fork, "vlmaps").n == 50  # the fix the message gives


def test_live_vlmap_nan_rows_get_a_fix_the_live_adapter_takes():
    """The NaN error once advised check_finite=False, an option vlmaps-live refuses."""
    arrays = mobile_map(n=15, d=D)
    feat = arrays["grid_feat"].copy()
    feat[4, 0] = np.nan
    live = SimpleNamespace(grid_feat=feat, grid_pos=arrays["grid_pos"])
    with pytest.raises(MapFormatError, match=r"'grid_feat'.*row 4") as err:
        read_map(live, "vlmaps-live")
    assert "check_finite" not in str(err.value)
    assert "grid_feat[~np.isfinite(vlmap.grid_feat).all(axis=1)] = 0" in str(err.value)
    feat[~np.isfinite(feat).all(axis=1)] = 0  # the fix the message gives
    assert read_map(live, "vlmaps-live").n == 15


def test_vlmaps_data_root_names_the_scene_folders_to_pass(tmp_path):
    """``quash query data chair`` with adapter vlmaps, where ``data/`` is VLMaps' data
    root (``data/<scene>/vlmap/vlmaps.h5df``), said only "not a VLMaps map file"; it now
    names the scene folders that hold a map, and each of them reads."""
    arrays = mobile_map()
    root = tmp_path / "data"
    for scene in ("5LpN3gDmAk7_1", "jh4fc5c5qoQ_1"):
        write_vlmaps_h5df(root / scene / "vlmap" / "vlmaps.h5df", arrays)
    (root / "logs").mkdir()  # a folder without a map is not named
    with pytest.raises(MapFormatError) as info:
        vlmaps().read(root)
    text = str(info.value)
    assert "not a VLMaps map file" in text and "pass one of them" in text
    assert str(root / "5LpN3gDmAk7_1") in text and str(root / "jh4fc5c5qoQ_1") in text
    assert str(root / "logs") not in text
    assert vlmaps().read(root / "5LpN3gDmAk7_1").n == vlmaps().read(root / "jh4fc5c5qoQ_1").n
    with pytest.raises(MapFormatError) as info:
        vlmaps().read(root / "logs")
    assert "pass one of them" not in str(info.value)


def test_an_option_from_the_configs_adapter_section_is_said_to_come_from_it(tmp_path):
    """docs/vlmaps.md's quash.yaml sets adapter: {cs: 0.05}; on a camera-base map that
    stores cs = 0.04 the error said "Drop the cs option" to a user who never passed one.
    It now names the config file's adapter: section; an option given to the call is the
    user's own and is told as before."""
    arrays, cam = camera_arrays()
    path = write_vlmaps_h5df(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays, camera=cam)
    config = tmp_path / "quash.yaml"
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0]}}\n"
        "heuristic: none\nadapter: {name: vlmaps, cs: 0.05}\ncache: false\n"
    )
    q = Quash.from_config(str(config))
    with pytest.raises(MapFormatError) as info:
        q.read_map(path)
    text = str(info.value)
    assert "option cs=0.05 disagrees" in text
    assert f"cs=0.05 comes from the adapter: section of {config}" in text
    with pytest.raises(MapFormatError) as info:
        q.read_map(path, cs=0.07)  # given by the caller: no config to blame
    assert "option cs=0.07 disagrees" in str(info.value)
    assert "adapter: section" not in str(info.value)
    assert q.read_map(path, cs=0.04).voxel_size == pytest.approx(0.04)


def test_an_option_a_camera_base_map_cannot_use_is_refused_saying_why(tmp_path):
    """On a camera-base map a gs option was silently ignored (its cells are placed by
    pcd_min and cs), and cs=abc said it 'disagrees with the map'. gs is now refused,
    file and live object alike, and a value that is not a number is said to be one;
    a gs from the config's adapter: section names that section."""
    arrays, cam = camera_arrays()
    path = write_vlmaps_h5df(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", arrays, camera=cam)
    gs = "option gs=400 does not apply to a camera-base map: its cells are placed by pcd_min"
    with pytest.raises(MapFormatError, match=gs + r".*Drop the gs option"):
        read_map(path, gs=400)
    live = SimpleNamespace(
        grid_feat=arrays["grid_feat"], grid_pos=arrays["grid_pos"], **cam, gs=1000
    )
    live.map_config = {"pose_info": {"pose_type": "camera_base"}}
    with pytest.raises(MapFormatError, match=gs):
        read_map(live, "vlmaps-live", gs=400)
    assert read_map(live, "vlmaps-live").n == 25  # its own gs attribute is no option
    with pytest.raises(MapFormatError) as info:
        read_map(path, cs="abc")
    assert str(info.value) == (
        f"{path}: option cs='abc' is not a number. Drop the cs option: camera-base maps "
        "store their cell size."
    )
    mobile = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=5, d=D))
    with pytest.raises(MapFormatError, match=r"option gs='x' is not a number\. Drop the gs"):
        read_map(mobile, gs="x")
    config = tmp_path / "quash.yaml"
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0]}}\n"
        "heuristic: none\nadapter: {name: vlmaps, gs: 1000}\ncache: false\n"
    )
    with pytest.raises(MapFormatError, match=r"gs=1000 comes from the adapter: section of"):
        Quash.from_config(str(config)).read_map(path)


def test_a_gs_or_cs_option_that_is_not_a_number_names_the_option_and_the_fix(tmp_path):
    """On a mobile-base file without occupied_ids, gs='x' said 'cannot read the VLMaps
    map (invalid literal for int() ...)' and gs=12.5 was cut to 12; on a live map with no
    cs of its own, cs='abc' failed with float()'s ValueError. Each now names the option,
    the map and what to give it; a whole number written as text still reads."""
    path = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=5, d=D), drop=("occupied_ids",))
    gs_fix = (
        "Give the map config's grid_size, in cells per side (VLMaps' default: 1000), or drop "
        "the gs option."
    )
    cs_fix = (
        "Give the map config's cell_size, in metres (VLMaps' default: 0.05), or drop the cs option."
    )
    for bad in ("x", "12.5", 12.5, True):
        with pytest.raises(MapFormatError) as info:
            read_map(path, gs=bad)
        assert str(info.value) == f"{path}: option gs={bad!r} is not a whole number. {gs_fix}"
    assert read_map(path, gs="60").source["gs"] == 60
    with pytest.raises(MapFormatError) as info:
        read_map(path, cs="abc")
    assert str(info.value) == f"{path}: option cs='abc' is not a number. {cs_fix}"
    arrays = mobile_map(n=5, d=D)
    live = SimpleNamespace(grid_feat=arrays["grid_feat"], grid_pos=arrays["grid_pos"])
    live.map_config = {"pose_info": {"pose_type": "mobile_base"}}
    adapter = registry.create("adapters", "vlmaps-live")
    with pytest.raises(MapFormatError) as info:
        adapter.read(live, cs="abc")
    where = "live SimpleNamespace object"
    assert str(info.value) == f"{where}: option cs='abc' is not a number. {cs_fix}"
    with pytest.raises(MapFormatError) as info:
        adapter.read(live, gs="x")
    assert str(info.value) == f"{where}: option gs='x' is not a whole number. {gs_fix}"
    assert adapter.read(live, cs="0.1").voxel_size == pytest.approx(0.1)
    config = tmp_path / "quash.yaml"  # an option from the config says where it came from
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0]}}\n"
        "heuristic: none\nadapter: {name: vlmaps, gs: x}\ncache: false\n"
    )
    with pytest.raises(MapFormatError, match=r"gs='x' comes from the adapter: section of"):
        Quash.from_config(str(config)).read_map(path)


def test_a_gs_or_cs_option_of_zero_or_less_is_refused_where_it_is_read(tmp_path):
    """gs=0 or a negative gs on a mobile-base map without occupied_ids was reported only
    as 'grid_pos holds rows/columns outside [0, 0)', and cs=0 as 'cell size cs must be a
    positive number' naming neither the option nor the fix. Each now names the option,
    the map and what to give it, file and live object alike."""
    path = write_vlmaps_h5df(tmp_path / "m.h5df", mobile_map(n=5, d=D), drop=("occupied_ids",))
    gs_fix = (
        "Give the map config's grid_size, in cells per side (VLMaps' default: 1000), or drop "
        "the gs option."
    )
    cs_fix = (
        "Give the map config's cell_size, in metres (VLMaps' default: 0.05), or drop the cs option."
    )
    arrays = mobile_map(n=5, d=D)
    live = SimpleNamespace(grid_feat=arrays["grid_feat"], grid_pos=arrays["grid_pos"])
    live.map_config = {"pose_info": {"pose_type": "mobile_base"}}
    adapter = registry.create("adapters", "vlmaps-live")
    for source, where in ((path, str(path)), (live, "live SimpleNamespace object")):
        for bad in (0, -4, "0", -1.0):
            with pytest.raises(MapFormatError) as info:
                adapter.read(source, gs=bad) if source is live else read_map(source, gs=bad)
            msg = f"{where}: option gs={bad!r} must be a positive whole number. {gs_fix}"
            assert str(info.value) == msg
        for bad, size in ((0, "positive"), (-0.05, "positive"), ("inf", "finite, positive")):
            with pytest.raises(MapFormatError) as info:
                adapter.read(source, cs=bad) if source is live else read_map(source, cs=bad)
            assert (
                str(info.value) == f"{where}: option cs={bad!r} must be a {size} number. {cs_fix}"
            )
    assert read_map(path, gs="60", cs="0.1").source["gs"] == 60


def test_a_scene_with_both_releases_maps_says_which_it_read(tmp_path, caplog):
    """A scene folder holding VLMaps' 3D vlmap/vlmaps.h5df and the 2023 top-down
    map/grid_lseg_1.npy: auto reads the 3D map, as before, and now says so and how to
    read the other; the 2D adapter still reads the same folder when named."""
    import logging

    from quash_plugins.adapters import read_map

    scene = tmp_path / "scene"
    h5 = write_vlmaps_h5df(scene / "vlmap" / "vlmaps.h5df", mobile_map(d=8))
    write_vlmaps_2d(scene, d=8)
    with caplog.at_level(logging.INFO, logger="quash_plugins.adapters"):
        lmap = read_map(scene)
    assert lmap.source["adapter"] == "vlmaps" and lmap.source["path"] == str(h5)
    said = " ".join(caplog.text.split())
    assert f"read the 3D map {h5}" in said
    assert "also holds the 2023 top-down map" in said and "--adapter vlmaps-2d" in said
    assert read_map(scene, adapter="vlmaps-2d").source["adapter"] == "vlmaps-2d"
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins.adapters"):
        read_map(h5)  # the file itself: nothing to say
    assert "top-down" not in caplog.text


def test_a_mobile_base_maps_default_cell_size_is_said_and_recorded(tmp_path, caplog):
    """Mobile-base files store no cell size, and every position scales by it: the
    default 0.05 m was taken silently; it is now said (info) and recorded as such."""
    import logging

    from quash_plugins.adapters import read_map

    h5 = write_vlmaps_h5df(tmp_path / "vlmap" / "vlmaps.h5df", mobile_map(d=8))
    with caplog.at_level(logging.INFO, logger="quash_plugins.adapters"):
        default = read_map(h5)
    assert default.source["cs"] == 0.05 and default.source["cs_from"] == "default"
    assert "store no cell size; positions use VLMaps' default cs = 0.05 m" in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="quash_plugins.adapters"):
        given = read_map(h5, cs=0.1)
    assert given.source["cs_from"] == "option" and "store no cell size" not in caplog.text
    assert np.allclose(given.positions, 2 * default.positions, atol=1e-5)


def test_too_few_label_names_names_the_file_found_beside_the_map(tmp_path, caplog):
    """VLMaps' obj2cls_dict.txt, found beside the scene, with fewer names than the map's
    grid_semantic ids: the padding warning named neither that file nor the map."""
    import logging

    from quash_plugins.adapters import read_map

    h5 = write_vlmaps_h5df(
        tmp_path / "scene" / "vlmap" / "vlmaps.h5df", mobile_map(d=8), semantic=np.arange(50) % 4
    )
    names = tmp_path / "scene" / "obj2cls_dict.txt"
    names.write_text("0: 0, chair\n1: 1, sofa\n")
    with caplog.at_level(logging.WARNING, logger="quash_plugins.adapters"):
        lmap = read_map(h5)
    assert lmap.label_names == ["chair", "sofa", "label_2", "label_3"]
    said = " ".join(caplog.text.split())
    assert f"label ids in {h5} (grid_semantic) reach 3" in said
    assert f"only 2 label names were given in {names}" in said
    assert "add the missing names to that file" in said
