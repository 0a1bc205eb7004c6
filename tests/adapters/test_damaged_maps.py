"""Damaged maps give errors that name the file and the fix, never a silent empty result.

Reproduces the issue's inputs: a zarr store with a chunk deleted (read as zeros, 0
matches, exit 0), an all-zero map, a corrupt zarr chunk (``Zstd decompression error``),
an unreadable chunk, a declared shape of 1e11 rows (``MemoryError``), a symbolic-link
loop, and truncated files that ``--adapter auto`` answered with "No adapter recognises".
Then fuzzes damaged npz, zarr and HDF5 files: every outcome is a map or a QuashError.
"""

from __future__ import annotations

import errno
import io
import logging
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quash_plugins import Quash
from quash_plugins.adapters import read_map, write_npz_map, write_zarr_map
from quash_plugins.cli.main import main
from quash_plugins.core import registry
from quash_plugins.core.errors import MapFormatError, QuashError
from quash_plugins.core.interfaces import MapAdapter
from quash_plugins.core.types import LatentMap

zarr = pytest.importorskip("zarr")


def _query(world, path, *extra):
    return main(["query", str(path), "chair", "-c", str(world["config"]), *map(str, extra)])


@pytest.fixture
def store(tiny_world, tmp_path):
    """The tiny world's map as a zarr store in 4 row chunks."""
    lmap = read_map(tiny_world["map"])
    return write_zarr_map(lmap, tmp_path / "map.zarr", chunk_mb=0.01)


# ---------------------------------------------------------------------- missing chunks
@pytest.mark.parametrize("backend", ["numpy", "dask"])
def test_a_deleted_chunk_is_an_error_naming_the_chunk_and_rows(tiny_world, store, capsys, backend):
    (store / "embeddings" / "c" / "1" / "0").unlink()
    assert _query(tiny_world, store, "--backend", backend) == 1
    err = capsys.readouterr().err
    assert "1 of 4 chunks of 'embeddings' are missing" in err and "c/1/0 (rows 163-325)" in err
    assert "quash convert" in err and "unexpected" not in err


def test_a_deleted_row_array_chunk_is_an_error_too(store):
    (store / "labels" / "c" / "0").unlink()
    with pytest.raises(MapFormatError, match="chunks of 'labels' are missing"):
        read_map(store)


def test_all_zero_chunks_are_written_so_they_are_not_missing(tmp_path):
    emb = np.zeros((40, 4), np.float32)
    emb[30:] = 1.0
    path = write_zarr_map(LatentMap(emb), tmp_path / "z.zarr", chunk_mb=0.0001)
    assert read_map(path).n == 40  # zero chunks are stored, so nothing is "missing"


def test_a_foreign_store_with_missing_chunks_warns_with_the_share(tiny_world, tmp_path, caplog):
    path = tmp_path / "foreign.zarr"
    group = zarr.open_group(str(path), mode="w", zarr_format=3)
    arr = group.create_array("embeddings", shape=(600, 16), chunks=(150, 16), dtype="float32")
    arr[:] = np.asarray(read_map(tiny_world["map"]).embeddings)
    shutil.rmtree(path / "embeddings" / "c" / "3")
    caplog.set_level(logging.WARNING)
    result = Quash.from_config(tiny_world["config"]).query(path, "chair")
    assert "1 of 4 chunks of 'embeddings' are missing" in caplog.text
    assert "about 25.0% of the rows" in caplog.text
    assert not result.mask[450:].any()


# ---------------------------------------------------------------------- unobserved maps
def test_an_all_zero_map_warns_that_nothing_can_match(tiny_world, tmp_path, capsys):
    path = write_npz_map(LatentMap(np.zeros((50, 16), np.float32)), tmp_path / "zeros.npz")
    assert _query(tiny_world, path) == 0
    err = " ".join(capsys.readouterr().err.split())  # the log handler wraps lines
    assert "every one of its 50 items has an all-zero embedding" in err


def test_a_mostly_unobserved_map_warns_with_the_share(tiny_world, tmp_path, caplog):
    emb = np.asarray(read_map(tiny_world["map"]).embeddings).copy()
    emb[:420] = 0
    path = write_npz_map(LatentMap(emb), tmp_path / "sparse.npz")
    caplog.set_level(logging.WARNING)
    Quash.from_config(tiny_world["config"]).query(path, "chair")
    assert "420 of 600 items (70.0%) have all-zero embeddings" in caplog.text
    caplog.clear()
    Quash.from_config(tiny_world["config"]).query(tiny_world["map"], "chair")
    assert "all-zero" not in caplog.text  # a fully observed map is quiet


# ---------------------------------------------------------------------- unreadable rows
@pytest.mark.parametrize("backend", ["numpy", "dask"])
def test_a_corrupt_chunk_names_the_file(tiny_world, store, capsys, backend):
    (store / "embeddings" / "c" / "2" / "0").write_bytes(b"garbage")
    assert _query(tiny_world, store, "--backend", backend) == 1
    err = capsys.readouterr().err
    assert f"{store}: cannot read it" in err and "decompression" in err
    assert "damaged" in err and "unexpected" not in err
    # the rows, and the chunk file to check or copy again (on Dask too)
    assert "zarr chunk embeddings/c/2/0)" in err and "rows " in err, err
    if backend == "dask":  # the command closed the cluster it started, error or not
        distributed = pytest.importorskip("distributed")
        with pytest.raises(ValueError):
            distributed.default_client()


class _Unreadable:
    """Embeddings whose rows raise like a chunk file the user may not read."""

    shape, dtype, ndim = (10, 4), np.dtype("float32"), 2

    def __getitem__(self, key):
        raise PermissionError(errno.EACCES, "Permission denied", "/maps/m.zarr/embeddings/c/0/0")


def test_an_unreadable_chunk_names_the_chunk_file():
    q = Quash(
        registry.create("encoders", "table", table={"chair": [1, 0, 0, 0], "other": [0, 1, 0, 0]}),
        classifier=registry.create("classifiers", "contrast"),
        negatives=["other"],
    )
    lmap = LatentMap(_Unreadable(), source={"path": "/maps/m.zarr"})
    with pytest.raises(MapFormatError) as info:
        q.query(lmap, "chair")
    msg = str(info.value)
    assert "permission denied reading /maps/m.zarr/embeddings/c/0/0" in msg and "rows 0-9" in msg


# ---------------------------------------------------------------------- declared shapes
def _npz_declaring(path: Path, shape) -> Path:
    buf = io.BytesIO()
    header = {"descr": "<f4", "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_2_0(buf, header)
    buf.write(np.zeros(64, np.float32).tobytes())
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("embeddings.npy", buf.getvalue())
    return path


def test_a_huge_declared_shape_is_refused_before_allocating(tiny_world, tmp_path, capsys):
    path = _npz_declaring(tmp_path / "huge.npz", (10**11, 16))
    assert _query(tiny_world, path) == 1
    err = capsys.readouterr().err
    assert "declares shape (100000000000, 16) float32 (5.8 TiB)" in err and "truncated" in err


def test_memory_errors_of_any_adapter_name_the_file(tmp_path):
    class Greedy(MapAdapter):
        name = "greedy-test"

        def sniff(self, source):
            return False

        def read(self, source, **options):
            raise MemoryError("Unable to allocate 1.09 TiB")

    registry.register("adapters", "greedy-test", Greedy)
    try:
        (tmp_path / "m.bin").write_bytes(b"x")
        with pytest.raises(MapFormatError) as info:
            read_map(tmp_path / "m.bin", "greedy-test")
        msg = str(info.value)
        assert str(tmp_path / "m.bin") in msg and "more memory" in msg and "1.09 TiB" in msg
    finally:
        registry.unregister("adapters", "greedy-test")


# ---------------------------------------------------------------------- paths
def test_symbolic_link_loop_and_broken_link_are_clear(tiny_world, tmp_path, capsys):
    (tmp_path / "a.npz").symlink_to(tmp_path / "b.npz")
    (tmp_path / "b.npz").symlink_to(tmp_path / "a.npz")
    assert _query(tiny_world, tmp_path / "a.npz") == 1
    assert "symbolic-link loop" in capsys.readouterr().err
    (tmp_path / "gone.npz").symlink_to(tmp_path / "nothing.npz")
    assert _query(tiny_world, tmp_path / "gone.npz") == 1
    assert "which does not exist" in capsys.readouterr().err


def test_out_onto_a_folder_or_into_an_unwritable_one(tiny_world, tmp_path, capsys, monkeypatch):
    (tmp_path / "r.npz").mkdir()
    assert _query(tiny_world, tiny_world["map"], "--out", tmp_path / "r.npz") == 2
    assert "is a folder" in capsys.readouterr().err
    from quash_plugins.core import atomic

    monkeypatch.setattr(atomic.os, "access", lambda *a, **k: False)  # as a non-root user
    assert _query(tiny_world, tiny_world["map"], "--out", tmp_path / "x" / "r.npz") == 0
    assert _query(tiny_world, tiny_world["map"], "--out", tmp_path / "r2.npz") == 2
    err = capsys.readouterr().err
    assert f"--out {tmp_path / 'r2.npz'}: the folder {tmp_path} is not writable" in err


# ---------------------------------------------------------------------- adapter: auto
def test_auto_reports_the_claimed_adapters_own_error(tiny_world, tmp_path, capsys):
    h5py = pytest.importorskip("h5py")
    trunc = tmp_path / "trunc.npz"
    trunc.write_bytes(tiny_world["map"].read_bytes()[:300])
    h5 = tmp_path / "vlmaps.h5df"
    with h5py.File(h5, "w") as f:
        f["grid_feat"] = np.ones((5, 4), np.float32)
    h5.write_bytes(h5.read_bytes()[:1000])
    bad_store = tmp_path / "m.zarr"
    bad_store.mkdir()
    (bad_store / "zarr.json").write_text("{ not json")
    for path, name in ((trunc, "npz"), (h5, "vlmaps"), (bad_store, "zarr")):
        assert _query(tiny_world, path) == 1
        err = capsys.readouterr().err
        assert f"looks like a {name!r} map" in err, err
        assert "No adapter recognises" not in err
    other = tmp_path / "notes.txt"
    other.write_text("hello")
    assert _query(tiny_world, other) == 1
    assert "No adapter recognises" in capsys.readouterr().err


# ---------------------------------------------------------------------- fuzz
FUZZ = settings(
    max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


def _read_all(source):
    """Open and read every row as the engine does (its read errors are QuashErrors)."""
    from quash_plugins.engine.classify import read_blocks

    try:
        lmap = read_map(source)
        for _ in read_blocks(lmap, 7):
            pass
    except QuashError:
        pass


def _damage(data: bytes, cut: int, flips: list[tuple[int, int]]) -> bytes:
    out = bytearray(data[: max(0, len(data) - cut)])
    for pos, bit in flips:
        if out:
            out[pos % len(out)] ^= 1 << bit
    return bytes(out)


DAMAGE = {
    "cut": st.integers(0, 400),
    "flips": st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 7)), max_size=4),
}


@FUZZ
@given(**DAMAGE)
def test_fuzzed_npz_files_read_or_fail_with_quash_errors(tiny_world, cut, flips):
    data = _damage(tiny_world["map"].read_bytes(), cut, flips)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "m.npz"
        path.write_bytes(data)
        _read_all(path)


@FUZZ
@given(chunk=st.integers(0, 3), **DAMAGE)
def test_fuzzed_zarr_chunks_read_or_fail_with_quash_errors(tiny_world, chunk, cut, flips):
    lmap = read_map(tiny_world["map"])
    with tempfile.TemporaryDirectory() as tmp:
        path = write_zarr_map(lmap, Path(tmp) / "m.zarr", chunk_mb=0.01)
        target = path / "embeddings" / "c" / str(chunk) / "0"
        target.write_bytes(_damage(target.read_bytes(), cut, flips))
        meta = path / "zarr.json"
        if flips and flips[0][1] == 0:  # sometimes damage the metadata instead
            meta.write_bytes(_damage(meta.read_bytes(), cut % 50, flips))
        _read_all(path)


@FUZZ
@given(**DAMAGE)
def test_fuzzed_hdf5_maps_read_or_fail_with_quash_errors(cut, flips):
    h5py = pytest.importorskip("h5py")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "vlmaps.h5df"
        rng = np.random.default_rng(0)
        with h5py.File(path, "w") as f:
            f["grid_feat"] = rng.normal(size=(20, 4)).astype(np.float32)
            f["grid_pos"] = rng.integers(0, 10, size=(20, 3)).astype(np.int32)
            f["occupied_ids"] = np.full((10, 10, 10), -1, np.int32)
        path.write_bytes(_damage(path.read_bytes(), cut * 10, flips))
        _read_all(path)
