"""Empty maps (N = 0: upstream writes them when nothing was fused) give empty results.

A query on an empty map is an empty result with an :class:`EmptyMapWarning`, never an
error, through every executor, the refinement pass, instance grouping, the result
writers, ``quash convert`` and the viewer.
"""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import LatentMap, Quash, registry
from quash_plugins.core.errors import EmptyMapWarning, MapFormatError
from quash_plugins.encoders import TableEncoder

TABLE = {
    "chair": [1.0, 0.0, 0.0],
    "sofa": [0.7, 0.0, 0.7],
    "other": [0.0, 1.0, 0.0],
    "background": [0.0, 0.0, 1.0],
    "nothing": [0.0, 0.7, 0.7],
}


def empty_map(kind: str = "voxels") -> LatentMap:
    extra = {}
    if kind == "voxels":
        extra = {"grid_index": np.zeros((0, 3), np.int64), "voxel_size": 0.05}
    return LatentMap(
        np.zeros((0, 3), np.float16),
        kind=kind,
        positions=np.zeros((0, 3), np.float32),
        colors=np.zeros((0, 3), np.uint8),
        labels=np.zeros(0, np.int64),
        label_names=["chair"],
        normalize=True,
        source={"path": "empty.h5df"},
        **extra,
    )


def quash(classifier: str = "contrast", **kw) -> Quash:
    return Quash(
        TableEncoder(table=TABLE), classifier=registry.create("classifiers", classifier), **kw
    )


def test_no_feature_dimension_is_still_an_error():
    with pytest.raises(MapFormatError, match="no feature dimension"):
        LatentMap(np.zeros((0, 0), np.float32))


@pytest.mark.parametrize("classifier", ["contrast", "svm-rbf", "cosine-threshold"])
@pytest.mark.parametrize("kind", ["voxels", "points"])
def test_query_on_empty_map_is_empty_with_warning(classifier, kind):
    lmap = empty_map(kind)
    with pytest.warns(EmptyMapWarning, match=r"empty\.h5df is empty"):
        results = quash(classifier, refine={}).query_many(lmap, ["chair", "sofa"])
    for r in results:
        assert r.mask.shape == (0,) and r.mask.dtype == bool
        assert r.scores.shape == (0,) and r.display_scores.shape == (0,)
        assert r.n_matched == 0 and r.instances == []
        assert r.queryset.provenance["refine"]["applied"] is False


def test_dask_backend_and_lazy_zarr(tmp_path):
    pytest.importorskip("dask")
    pytest.importorskip("zarr")
    lmap = empty_map()
    with pytest.warns(EmptyMapWarning):
        r = quash(backend="dask").query(lmap, "chair")
    assert r.mask.shape == (0,)
    with pytest.warns(EmptyMapWarning):
        lazy = quash().query_many_lazy(lmap, ["chair", "sofa"])
    path = lazy.to_zarr(tmp_path / "r.zarr")
    import zarr

    store = zarr.open_group(str(path), mode="r")
    assert store["masks"].shape == (2, 0) and store["scores"].shape == (2, 0)


def test_results_file_and_convert(tmp_path):
    from quash_plugins.adapters import read_map, write_npz_map, write_zarr_map
    from quash_plugins.engine.results import write_results_npz

    lmap = empty_map()
    with pytest.warns(EmptyMapWarning):
        results = quash().query_many(lmap, ["chair", "sofa"])
    out = write_results_npz(tmp_path / "r.npz", results)
    with np.load(out) as z:
        assert z["masks"].shape == (2, 0) and z["scores"].dtype == np.float32
    back = read_map(write_npz_map(lmap, tmp_path / "m.npz"))
    assert (back.n, back.dim, back.dtype) == (0, 3, np.float16)
    pytest.importorskip("zarr")
    back = read_map(write_zarr_map(lmap, tmp_path / "m.zarr"))
    assert (back.n, back.dim) == (0, 3)


@pytest.mark.parametrize("kind", ["voxels", "points"])
def test_viewer_logs_an_empty_map(tmp_path, kind):
    rr = pytest.importorskip("rerun")
    from quash_plugins.viewer import RerunLogger

    lmap = empty_map(kind)
    lmap.colors = None  # the PCA colouring path too
    with pytest.warns(EmptyMapWarning):
        result = quash().query(lmap, "chair")
    rec = rr.RecordingStream("quash-empty")
    path = tmp_path / "e.rrd"
    rec.save(path)
    logger = RerunLogger(rec)
    logger.log_map(lmap)
    logger.log_result(lmap, result, index=0)
    logger.close()
    rec.disconnect()
    assert path.stat().st_size > 0
