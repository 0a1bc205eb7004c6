"""Queries never write into a map (issue 17, item 2).

Every built-in adapter's maps are written (its own ``write_example``, and float32
variants that the adapter hands out as read-only memory-map views: ``.npy`` image
features, dense OpenLex3D embeddings, OpenScene's per-point ``.npy`` features, full 2D
VLMaps grids), read, and queried with normalisation on through every path that reads
rows: ``LatentMap.iter_chunks``, the in-memory pass with a stacked SVM, a cosine rule
and a plain scikit-learn estimator, ``Quash.query``, the Dask pass and the device pass
(torch on the CPU). The files' hash must not change, memory maps must be read-only, and
a caller's own float32 array must come back unchanged.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from _cf_writers import save_openlex3d, tree_hash

from quash_plugins import Quash, registry
from quash_plugins.core.types import LatentMap
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine import classify_local

WORDS = ["chair", "other", "background", "nothing"]
CLASSIFIERS = [
    ("contrast", {}),
    ("svm-rbf", {"gamma": 2.0}),
    ("sklearn", {"estimator": "sklearn.linear_model.LogisticRegression"}),
]


def _example(name: str, root: Path) -> tuple[Path, dict]:
    return registry.load("adapters", name)().write_example(root), {}


def _image_features_npy(root: Path) -> tuple[Path, dict]:
    folder = root / "frames"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        np.save(folder / f"frame{i}.npy", rng.normal(size=(4, 6, 12)).astype(np.float32))
    return folder, {}


def _openlex3d_dense(root: Path) -> tuple[Path, dict]:
    pytest.importorskip("open3d")
    rng = np.random.default_rng(0)
    feat = (rng.normal(size=(40, 12)) * rng.uniform(0.5, 4, (40, 1))).astype(np.float32)
    return save_openlex3d(root / "ol", rng.normal(size=(40, 3)), None, feat, np.arange(40)), {}


def _openscene_npy(root: Path) -> tuple[Path, dict]:
    pytest.importorskip("torch")
    pt = registry.load("adapters", "openscene")().write_example(root)  # the scene's points
    n = 120  # the example scene's number of points
    feat = np.random.default_rng(1).normal(size=(n, 16)).astype(np.float32)
    path = pt.parent / "scene0000_00_openscene_feat_ensemble.npy"
    np.save(path, feat)
    return path, {}


def _vlmaps_2d_full(root: Path) -> tuple[Path, dict]:
    return registry.load("adapters", "vlmaps-2d")().write_example(root), {"keep_empty": True}


CASES = {
    "conceptfusion": lambda root: _example("conceptfusion", root),
    "image-features": lambda root: _example("image-features", root),
    "image-features-npy": _image_features_npy,
    "npz": lambda root: _example("npz", root),
    "openlex3d": lambda root: _example("openlex3d", root),
    "openlex3d-dense": _openlex3d_dense,
    "openscene": lambda root: _example("openscene", root),
    "openscene-npy": _openscene_npy,
    "vlmaps": lambda root: _example("vlmaps", root),
    "vlmaps-2d": lambda root: _example("vlmaps-2d", root),
    "vlmaps-2d-full": _vlmaps_2d_full,
    "zarr": lambda root: _example("zarr", root),
}
#: The cases whose rows come from a float32 read-only memory map: handed out as views of
#: it (the case issue 17 reports), or gathered from it (``openscene-npy``).
FLOAT32_MEMMAPS = {"image-features-npy", "openlex3d-dense", "openscene-npy", "vlmaps-2d-full"}


def test_every_file_adapter_is_covered():
    adapters = {c.removesuffix("-npy").removesuffix("-dense").removesuffix("-full") for c in CASES}
    builtin = {n for n in registry.available("adapters") if n != "vlmaps-live"}  # a live object
    assert builtin <= adapters


def _table(dim: int) -> dict[str, list[float]]:
    rng = np.random.default_rng(7)
    T = rng.normal(size=(len(WORDS), dim))
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    return {w: T[i].tolist() for i, w in enumerate(WORDS)}


def _fitted(dim: int) -> list:
    T = np.asarray(list(_table(dim).values()), np.float32)
    y = np.array([1, 0, 0, 0])
    return [registry.create("classifiers", n, **p).fit(T, y) for n, p in CLASSIFIERS]


def _memmaps(emb) -> list[np.memmap]:
    """The memory maps behind ``emb``: itself, the array a row view wraps, or the array
    the rows it hands out are views of."""
    found = []
    wrapped = (getattr(emb, a, None) for a in ("base", "table", "arr", "source"))
    for obj in (emb, *wrapped, emb[0:2]):
        while isinstance(obj, np.ndarray):
            if isinstance(obj, np.memmap):
                found.append(obj)
                break
            obj = obj.base
    return found


def _every_reader(lmap: LatentMap) -> list[np.ndarray]:
    """Run every path that reads rows; return the contrast scores of the in-memory pass."""
    fitted = _fitted(lmap.dim)
    blocks = [b for _, _, b in lmap.iter_chunks(7)]
    assert sum(len(b) for b in blocks) == lmap.n
    scores, observed = classify_local(lmap, fitted, chunk_bytes=4096)  # a few rows a chunk
    q = Quash(
        TableEncoder(table=_table(lmap.dim)),
        classifier=registry.create("classifiers", "contrast"),
        instances=None,
    )
    q.query(lmap, "chair")
    from quash_plugins.engine import classify_dask

    dask_scores, _ = classify_dask(lmap, fitted, chunk_bytes=4096)  # local threads
    for a, b in zip(scores, dask_scores):
        np.testing.assert_array_equal(a, b)  # the same blocks: the same bits
    try:
        import torch  # noqa: F401
    except ImportError:
        return scores
    from quash_plugins.engine.device import DeviceMap, classify_on_device

    dev, dev_obs = classify_on_device(DeviceMap(lmap, "cpu"), fitted, use_triton=False)
    np.testing.assert_array_equal(dev_obs, observed)
    return scores


@pytest.mark.parametrize("case", sorted(CASES))
def test_queries_leave_the_files_unchanged(tmp_path, case):
    root = tmp_path / "data"
    root.mkdir()
    source, options = CASES[case](root)
    before = tree_hash(root)
    adapter = case.removesuffix("-npy").removesuffix("-dense").removesuffix("-full")
    lmap = registry.load("adapters", adapter)().read(source, **options)
    maps = _memmaps(lmap.embeddings)
    assert all(not m.flags.writeable for m in maps)  # opened read-only
    if case in FLOAT32_MEMMAPS:
        assert maps and lmap.embeddings.dtype == np.float32
    for normalize in (lmap.normalize, True):
        scores = _every_reader(dataclasses.replace(lmap, normalize=normalize))
        E = np.asarray(lmap.embeddings[: lmap.n], np.float64)
        if normalize:
            n = np.linalg.norm(E, axis=1, keepdims=True)
            E = np.divide(E, n, out=np.zeros_like(E), where=n > 0)
        contrast = _fitted(lmap.dim)[0]
        ref = contrast.decision_function(E.astype(np.float32))
        np.testing.assert_allclose(scores[0], ref, atol=1e-5)
    assert tree_hash(root) == before


@pytest.mark.parametrize("writeable", [True, False])
def test_a_users_float32_array_is_never_normalised(writeable):
    rng = np.random.default_rng(3)
    E = (rng.normal(size=(300, 12)) * rng.uniform(0.2, 5, (300, 1))).astype(np.float32)
    E[::11] = 0
    before = E.copy()
    E.flags.writeable = writeable  # a read-only array must work too
    _every_reader(LatentMap(E, normalize=True))
    np.testing.assert_array_equal(E, before)
    live = SimpleNamespace(grid_feat=E, grid_pos=np.full((300, 3), 5), gs=10)
    lmap = registry.load("adapters", "vlmaps-live")().read(live)
    assert lmap.embeddings is E and lmap.normalize
    _every_reader(lmap)
    np.testing.assert_array_equal(E, before)


def test_prepare_block_writes_only_a_block_it_owns():
    from quash_plugins.core.types import prepare_block

    E = np.full((4, 3), 2.0, np.float32)
    out = prepare_block(E, 0, normalize=True)
    assert (E == 2.0).all() and np.allclose(np.linalg.norm(out, axis=1), 1.0)
    mine = E.copy()
    assert prepare_block(mine, 0, normalize=True, owned=True) is mine  # in place: a copy
    assert np.allclose(np.linalg.norm(mine, axis=1), 1.0)
