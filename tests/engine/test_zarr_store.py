"""The zarr map store, the zarr adapter and as_dask wrappers (no cluster needed)."""

from __future__ import annotations

import pickle

import dask.array as da
import numpy as np
import pytest
import zarr  # noqa: F401 - the zarr store is tested here

from quash_plugins.adapters import detect_adapter, read_map, write_zarr_map
from quash_plugins.core.errors import MapFormatError, QuashError
from quash_plugins.core.types import FrameInfo, LatentMap
from quash_plugins.engine import as_dask, classify_dask


def _map(n=500, d=8, dtype=np.float16, seed=0):
    rng = np.random.default_rng(seed)
    emb = rng.normal(size=(n, d)).astype(dtype)
    emb[::50] = 0
    return LatentMap(
        emb,
        kind="voxels",
        positions=rng.uniform(0, 3, size=(n, 3)).astype(np.float32),
        colors=rng.integers(0, 255, size=(n, 3), dtype=np.uint8),
        labels=rng.integers(0, 3, size=n),
        label_names=["floor", "chair", "table"],
        voxel_size=0.05,
        grid_index=rng.integers(0, 100, size=(n, 3)),
        normalize=True,
        source={"encoder_hint": "test 8"},
    )


def test_round_trip_keeps_everything(tmp_path):
    m = _map()
    path = write_zarr_map(m, tmp_path / "m.zarr", chunk_mb=0.001)
    assert detect_adapter(path) == "zarr"
    back = read_map(path)
    assert back.embeddings.dtype == np.float16
    assert back.embeddings.chunks[0] < m.n  # really chunked by rows
    np.testing.assert_array_equal(np.asarray(back.embeddings[...]), m.embeddings)
    for key in ("positions", "colors", "labels", "grid_index"):
        np.testing.assert_array_equal(getattr(back, key), getattr(m, key))
    assert back.kind == "voxels" and back.voxel_size == pytest.approx(0.05)
    assert back.label_names == m.label_names and back.normalize is True
    assert back.source["encoder_hint"] == "test 8" and back.source["adapter"] == "zarr"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.zarr"]  # no temp dirs left


def test_dask_option_and_frames(tmp_path):
    rng = np.random.default_rng(1)
    frames = [FrameInfo("a", 2, 3, 0), FrameInfo("b", 2, 2, 6)]
    m = LatentMap(rng.normal(size=(10, 4)).astype(np.float32), kind="pixels", frames=frames)
    path = write_zarr_map(m, tmp_path / "px.zarr")
    back = read_map(path, adapter="zarr", dask=True, chunk_rows=3)
    assert isinstance(back.embeddings, da.Array) and back.embeddings.chunks[0][0] == 3
    np.testing.assert_array_equal(back.embeddings.compute(), m.embeddings)
    assert back.frames == frames and back.kind == "pixels"


def test_overwrite_is_atomic_and_optional(tmp_path):
    path = write_zarr_map(_map(seed=1), tmp_path / "m.zarr")
    with pytest.raises(QuashError, match="m.zarr exists. Remove it or pass overwrite=True"):
        write_zarr_map(_map(seed=2), path, overwrite=False)
    m2 = _map(seed=2)
    write_zarr_map(m2, path)
    np.testing.assert_array_equal(np.asarray(read_map(path).embeddings[...]), m2.embeddings)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.zarr"]


def test_sniff_rejects_other_things(tmp_path):
    from quash_plugins.core import registry

    a = registry.create("adapters", "zarr")
    (tmp_path / "empty").mkdir()
    np.savez(tmp_path / "m.npz", embeddings=np.eye(3, dtype=np.float32))
    assert not a.sniff(tmp_path / "empty")
    assert not a.sniff(tmp_path / "m.npz")
    assert not a.sniff(tmp_path / "missing.zarr")
    assert not a.sniff(np.eye(3))
    assert a.sniff(a.write_example(tmp_path))


def test_bare_array_store_and_missing_embeddings(tmp_path):

    z = zarr.create_array(str(tmp_path / "bare.zarr"), shape=(20, 4), chunks=(5, 4), dtype="f4")
    z[:] = np.arange(80, dtype=np.float32).reshape(20, 4)
    assert detect_adapter(tmp_path / "bare.zarr") == "zarr"
    np.testing.assert_array_equal(
        np.asarray(read_map(tmp_path / "bare.zarr").embeddings[:2]),
        np.arange(8, dtype=np.float32).reshape(2, 4),
    )
    g = zarr.open_group(str(tmp_path / "g.zarr"), mode="w")
    g.create_array("positions", shape=(3, 3), dtype="f4")
    with pytest.raises(MapFormatError, match="missing array 'embeddings'.*Found: positions"):
        read_map(tmp_path / "g.zarr", adapter="zarr")


def test_as_dask_h5py_and_memmap_readers_pickle(tmp_path):
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(3)
    data = rng.normal(size=(103, 6)).astype(np.float32)
    with h5py.File(tmp_path / "m.h5", "w") as f:
        f.create_dataset("grp/emb", data=data)
    np.save(tmp_path / "m.npy", data)
    with h5py.File(tmp_path / "m.h5", "r") as f:
        x = as_dask(LatentMap(f["grp/emb"]), 10)
    # The file is closed now: the graph reopens it by name, and survives pickling.
    x = pickle.loads(pickle.dumps(x))
    assert x.chunks[0][:2] == (10, 10)
    np.testing.assert_array_equal(x.compute(), data)
    mm = np.load(tmp_path / "m.npy", mmap_mode="r")
    y = pickle.loads(pickle.dumps(as_dask(LatentMap(mm), 25)))
    assert len(pickle.dumps(y)) < data.nbytes  # the data is not inside the graph
    np.testing.assert_array_equal(y.compute(), data)


def test_classify_dask_threads_matches_reference():
    from quash_plugins.core import registry

    rng = np.random.default_rng(5)
    T = rng.normal(size=(4, 8)).astype(np.float32)
    clf = registry.create("classifiers", "contrast").fit(T, np.array([1, 0, 0, 0]))
    m = _map(n=300, seed=4)
    scores, observed = classify_dask(m, [clf], chunk_bytes=1000)
    E = m.embeddings.astype(np.float32)
    norms = np.linalg.norm(E, axis=1, keepdims=True)
    E = np.divide(E, norms, out=np.zeros_like(E), where=norms > 0)
    Tn = T / np.linalg.norm(T, axis=1, keepdims=True)
    expected = (E @ Tn[:1].T).max(1) - (E @ Tn[1:].T).max(1)
    np.testing.assert_allclose(scores[0], expected, atol=1e-5)
    np.testing.assert_array_equal(observed, norms[:, 0] > 0)


def test_nan_row_is_reported_with_its_index():
    from quash_plugins.core import registry
    from quash_plugins.core.errors import MapFormatError

    T = np.eye(4, dtype=np.float32)
    clf = registry.create("classifiers", "contrast").fit(T, np.array([1, 0, 0, 0]))
    emb = np.ones((100, 4), dtype=np.float32)
    emb[77, 2] = np.nan
    with pytest.raises(MapFormatError, match="row 77"):
        classify_dask(LatentMap(emb), [clf], chunk_bytes=16 * 10)


def test_backend_options_validate_without_starting_a_cluster():
    import argparse

    from quash_plugins.cli._backend_opts import add_backend_arguments, backend_overrides
    from quash_plugins.core.errors import QuashError, UsageError

    p = argparse.ArgumentParser()
    add_backend_arguments(p)
    assert backend_overrides(p.parse_args([])) == {}
    with pytest.raises(UsageError, match="--workers 2 needs --backend dask: add --backend"):
        backend_overrides(p.parse_args(["--workers", "2"]))
    for n in ("0", "-1"):
        with pytest.raises(UsageError, match=rf"--workers {n}: .* Give --workers N with N >= 1"):
            backend_overrides(p.parse_args(["--backend", "dask", "--workers", n]))
    # each its own message: not 'N >= 1' for a count that is fine beside --scheduler
    with pytest.raises(UsageError, match=r"--workers 2 starts a local cluster, --scheduler") as e:
        backend_overrides(p.parse_args(["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"]))
    assert "N >= 1" not in str(e.value)
    # --scheduler implies dask; an unreachable scheduler is a clear QuashError
    import dask

    with (
        dask.config.set({"distributed.comm.timeouts.connect": "1s"}),
        pytest.raises(QuashError, match="Cannot reach the Dask scheduler"),
    ):
        backend_overrides(p.parse_args(["--scheduler", "tcp://127.0.0.1:1"]))


def test_an_embeddings_folder_without_its_metadata_is_named(tmp_path):
    """A store whose embeddings/zarr.json is gone (a partial copy) says so, rather than
    'missing array' beside a folder that is plainly there."""
    import warnings

    from quash_plugins.adapters import write_zarr_map
    from quash_plugins.core.types import LatentMap

    store = tmp_path / "m.zarr"
    write_zarr_map(LatentMap(np.eye(6, 4, dtype=np.float32)), store)
    meta = store / "embeddings" / "zarr.json"
    assert meta.is_file()
    meta.unlink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # zarr's own warning is folded into the error
        with pytest.raises(MapFormatError, match=r"'embeddings' holds no zarr array metadata"):
            read_map(store, adapter="zarr")


def test_lazy_results_never_replace_a_store_that_is_not_a_results_store(tmp_path):
    """LazyQuery.to_zarr replaced any zarr store (overwrite=True by default): a map
    converted to zarr, given as the output, was lost. Only a results store it wrote (or
    an empty folder) is replaced; quash query --out refused it already."""
    from quash_plugins import Quash
    from quash_plugins.core.errors import UsageError
    from quash_plugins.encoders import TableEncoder

    words = ["chair", "other", "background", "nothing"]
    table = {w: np.eye(8, dtype=np.float32)[i].tolist() for i, w in enumerate(words)}
    q = Quash(TableEncoder(table=table), classifier="contrast", instances=None)
    src = write_zarr_map(_map(seed=1), tmp_path / "src.zarr")
    other = write_zarr_map(_map(seed=2), tmp_path / "other_map.zarr")
    before = sorted(p.name for p in other.iterdir())
    for overwrite, why in ((True, "not a previous results store"), (False, "exists")):
        with pytest.raises(UsageError, match=why):
            q.query_many_lazy(str(src), ["chair"]).to_zarr(other, overwrite=overwrite)
    assert sorted(p.name for p in other.iterdir()) == before  # the map is still there
    assert read_map(other).n == 500
    out = q.query_many_lazy(str(src), ["chair"]).to_zarr(tmp_path / "r.zarr")
    q.query_many_lazy(str(src), ["chair"]).to_zarr(out)  # a previous results store
    assert sorted(zarr_group_keys(out)) == ["masks", "observed", "scores"]


def zarr_group_keys(path):
    import zarr

    return list(zarr.open_group(str(path), mode="r").array_keys())


def test_scattered_rows_of_a_zarr_map_are_read_window_by_window(tmp_path, monkeypatch):
    """Refinement's samples and the presence check's regions are scattered rows: one
    fancy index on a zarr array decoded every stored chunk they touch at once (most of
    the map). take_rows reads bounded windows, and gives the rows the array holds."""
    from quash_plugins.engine import refine

    m = _map(n=500, d=8, dtype=np.float32)
    path = write_zarr_map(m, tmp_path / "m.zarr", chunk_mb=0.001)
    lmap = read_map(path)
    assert type(lmap.embeddings).__module__.startswith("zarr")
    index = np.random.default_rng(0).choice(500, size=60, replace=False)
    monkeypatch.setattr(refine, "TAKE_WINDOW_BYTES", 4 * 8 * 50)  # 50 rows a window
    windowed = []
    real = refine._take_windowed
    monkeypatch.setattr(refine, "_take_windowed", lambda *a: windowed.append(len(a[1])) or real(*a))
    got = refine.take_rows(lmap, index)
    assert windowed == [60]  # the zarr array went through the windows
    np.testing.assert_allclose(got, refine.take_rows(m, index), rtol=1e-6)
    assert windowed == [60]  # an in-memory array did not

    class Recording:  # the slices a window read asks for
        def __init__(self, a):
            self.a, self.slices = a, []

        def __getitem__(self, key):
            self.slices.append(key)
            return self.a[key]

    rec = Recording(np.asarray(m.embeddings, dtype=np.float32))
    rows = refine._take_windowed(rec, np.sort(index), 8)
    np.testing.assert_array_equal(rows, rec.a[np.sort(index)])
    assert all(isinstance(k, slice) and k.stop - k.start <= 50 for k in rec.slices)
    assert len(rec.slices) >= 500 // 50 - 1  # windows, not one read of the whole span


@pytest.mark.parametrize(
    "options, message",
    [
        ({"chunk_rows": -5}, "option 'chunk_rows' must be a whole number of rows >= 1"),
        ({"chunk_rows": 0}, "option 'chunk_rows' must be a whole number of rows >= 1"),
        ({"chunk_rows": "abc"}, "option 'chunk_rows'"),
        ({"chunk_rows": 2.5}, "option 'chunk_rows'"),
        ({"dask": "ture"}, "option 'dask' must be true or false; got 'ture'"),
    ],
)
def test_bad_zarr_adapter_options_are_named_not_blamed_on_the_file(tmp_path, options, message):
    """A bad chunk_rows surfaced as 'The file may be damaged or truncated'; chunk_rows=0
    was ignored and dask='ture' taken as true."""
    from quash_plugins.core import registry
    from quash_plugins.core.errors import ConfigError

    path = write_zarr_map(_map(), tmp_path / "m.zarr")
    with pytest.raises(ConfigError, match=message):
        registry.create("adapters", "zarr").read(path, **options)
    with pytest.raises(ConfigError, match=message):
        registry.create("adapters", "zarr", **options)
    assert read_map(path, "zarr", dask=True, chunk_rows=100).embeddings.chunks[0][0] == 100


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"chunk_mb": 0}, "chunk_mb must be a positive, finite number"),
        ({"chunk_mb": float("nan")}, "chunk_mb must be a positive, finite number"),
        ({"chunk_mb": float("inf")}, "chunk_mb must be a positive, finite number"),
        ({"backend": "dsak"}, "Unknown backend 'dsak'. Known: numpy, local, dask"),
        ({"client": "tcp://127.0.0.1:1"}, r"pass a dask.distributed.Client, e.g. Client\("),
    ],
)
def test_the_python_api_checks_what_a_config_checks(kwargs, message):
    """Quash(chunk_mb=0) ran one-row chunks for ever; backend='dsak' failed only at the
    first query, and an address as client= was blamed on the map."""
    from quash_plugins import Quash
    from quash_plugins.core.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        Quash.from_config({"heuristic": "none", "classifier": "contrast"}, **kwargs)


@pytest.mark.parametrize("value", [".nan", ".inf", "1e400", "0", "-1"])
def test_a_config_chunk_mb_that_is_not_finite_and_positive_is_refused(value):
    from quash_plugins import QuashConfig
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.core.yaml_files import load_yaml_text

    with pytest.raises(ConfigError, match="'chunk_mb' must be a positive, finite number"):
        QuashConfig.from_dict(load_yaml_text(f"chunk_mb: {value}\n"))
