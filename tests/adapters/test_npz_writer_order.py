"""The NPZ writers take the map first, as every map writer does.

``write_npz_map(lmap, path)`` and ``write_npz_streaming(lmap, path)``; the old
``(path, lmap)`` order still writes the same file for one release, with a
``DeprecationWarning`` naming the new order (pyproject turns that warning into an error
everywhere else, so no other test uses the old order).
"""

from __future__ import annotations

import warnings
import zipfile

import numpy as np
import pytest

from quash_plugins.adapters import write_npz_map
from quash_plugins.adapters._convert import write_npz_streaming
from quash_plugins.adapters._npz import NpzAdapter
from quash_plugins.core.types import LatentMap

WRITERS = [write_npz_map, write_npz_streaming]
ARRAYS = ("embeddings", "positions", "colors", "labels", "grid_index")


def _map() -> LatentMap:
    rng = np.random.default_rng(7)
    grid = rng.choice(1000, size=30, replace=False)
    idx = np.stack(np.unravel_index(grid, (10, 10, 10)), axis=1).astype(np.int32)
    return LatentMap(
        rng.normal(size=(30, 6)).astype(np.float32),
        kind="voxels",
        positions=(idx * 0.1).astype(np.float32),
        colors=rng.integers(0, 256, size=(30, 3), dtype=np.uint8),
        labels=rng.integers(0, 3, size=30),
        label_names=["floor", "chair", "table"],
        voxel_size=0.1,
        grid_index=idx,
    )


def _assert_same_map(back: LatentMap, lmap: LatentMap) -> None:
    for key in ARRAYS:
        np.testing.assert_array_equal(getattr(back, key), getattr(lmap, key), err_msg=key)
    assert back.label_names == lmap.label_names
    assert back.voxel_size == pytest.approx(lmap.voxel_size)
    assert back.kind == lmap.kind


@pytest.mark.parametrize("writer", WRITERS, ids=lambda w: w.__name__)
def test_the_map_first_writes_a_map_that_reads_back_without_a_warning(writer, tmp_path):
    lmap = _map()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = writer(lmap, tmp_path / "m.npz")
    assert out == tmp_path / "m.npz"
    _assert_same_map(NpzAdapter().read(out), lmap)


def test_write_npz_map_compresses_in_the_new_order(tmp_path):
    lmap = _map()
    out = write_npz_map(lmap, str(tmp_path / "c.npz"), compress=True)
    with zipfile.ZipFile(out) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_DEFLATED}
    _assert_same_map(NpzAdapter().read(out), lmap)


@pytest.mark.parametrize("writer", WRITERS, ids=lambda w: w.__name__)
def test_the_old_order_warns_naming_the_new_one_and_writes_the_same_file(writer, tmp_path):
    lmap = _map()
    new = writer(lmap, tmp_path / "new.npz")
    name = writer.__name__
    with pytest.warns(DeprecationWarning, match=rf"{name}\(lmap, path\)") as record:
        old = writer(tmp_path / "old.npz", lmap)
    assert old == tmp_path / "old.npz"
    assert [w.filename for w in record] == [__file__]  # attributed to the caller
    with np.load(new) as a, np.load(old) as b:
        assert sorted(a.files) == sorted(b.files)
        for key in a.files:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    _assert_same_map(NpzAdapter().read(old), lmap)


def test_the_old_order_keeps_its_keyword_and_positional_options(tmp_path):
    lmap = _map()
    with pytest.warns(DeprecationWarning):
        out = write_npz_map(tmp_path / "c.npz", lmap, True)
    with zipfile.ZipFile(out) as zf:
        assert {i.compress_type for i in zf.infolist()} == {zipfile.ZIP_DEFLATED}
    with pytest.warns(DeprecationWarning):
        out = write_npz_streaming(tmp_path / "s.npz", lmap, chunk_rows=4)
    _assert_same_map(NpzAdapter().read(out), lmap)


@pytest.mark.parametrize("writer", WRITERS, ids=lambda w: w.__name__)
def test_no_map_among_the_arguments_is_a_type_error_naming_the_order(writer, tmp_path):
    with pytest.raises(TypeError, match=rf"{writer.__name__}\(lmap, path\).*LatentMap.*str"):
        writer(str(tmp_path / "a.npz"), str(tmp_path / "b.npz"))
    with pytest.raises(TypeError, match=r"LatentMap.*ndarray"):
        writer(np.eye(3, dtype=np.float32), tmp_path / "b.npz")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("writer", WRITERS, ids=lambda w: w.__name__)
def test_a_map_without_a_path_is_a_type_error(writer, tmp_path):
    lmap = _map()
    with pytest.raises(TypeError, match=r"second argument must be the output path.*NoneType"):
        writer(lmap, None)
    with pytest.raises(TypeError, match=r"second argument must be the output path.*LatentMap"):
        writer(lmap, lmap)
