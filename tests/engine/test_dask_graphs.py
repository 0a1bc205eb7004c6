"""What a Dask pass puts into its task graph: references to the map's files and the
arrays scoring reads, never the whole feature table or every array a classifier keeps.

- OpenScene's fused features (a ``torch.save`` dict) and OpenLex3D's object table are
  read through memory maps that pickle as (path, offset, shape, dtype): the pickled graph
  is the same size for a table many times larger, and the answers equal the in-memory
  backend's (on a LocalCluster of one worker process, which unpickles the graph).
- The fitted classifiers travel once per pass, without scikit-learn's own float64 model,
  the training set or derived copies (the default config's refined SVMs were 4x what
  scoring reads): Dask's "Sending large graph" warning is not raised for a pass whose
  classifiers only a few MB of vectors need.
"""

from __future__ import annotations

import math
import pickle
import warnings

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")
cloudpickle = pytest.importorskip("cloudpickle")
torch = pytest.importorskip("torch")

from _dask_table import WORDS, one_worker_client  # noqa: E402
from _dask_table import table_quash as _quash  # noqa: E402
from _dask_table import words as _words  # noqa: E402
from _openscene_writers import preprocess_scannet, save_fused_feature  # noqa: E402

from quash_plugins.adapters import read_map  # noqa: E402
from quash_plugins.adapters._rows import IndexedRows  # noqa: E402
from quash_plugins.core import registry  # noqa: E402
from quash_plugins.core.types import LatentMap  # noqa: E402
from quash_plugins.engine import classify_dask, classify_local  # noqa: E402
from quash_plugins.engine.classify import BlockScorer  # noqa: E402
from quash_plugins.engine.dask_arrays import as_dask  # noqa: E402


@pytest.fixture(scope="module")
def client():
    """One worker process: every task and the graph are really pickled and unpickled."""
    yield from one_worker_client()


def _openscene(root, n: int, d: int, seed: int = 0):
    """A ScanNet-style scene written as OpenScene writes it; features near the words."""
    rng = np.random.default_rng(seed)
    vecs = _words(d)
    labels = rng.integers(0, 3, size=n)
    bank = np.stack([vecs[WORDS[k]] for k in labels]) + 0.6 * rng.normal(size=(n, d))
    bank *= rng.uniform(0.3, 3.0, size=(n, 1))
    preprocess_scannet(
        root / "scannet_3d" / "val" / "scene0001_00_vh_clean_2.pth",
        rng.uniform(-3, 3, size=(n, 3)),
        rng.integers(0, 256, size=(n, 3)),
        labels.astype(np.float64),
    )
    visible = np.flatnonzero(rng.random(n) < 0.8)
    (pt,) = save_fused_feature(bank, visible, n, root / "openseg", "scene0001_00", seed=seed)
    return pt, vecs


def _graph_bytes(lmap: LatentMap, chunks: int = 3) -> int:
    """The pickled task graph of the map's embeddings, in ``chunks`` row chunks."""
    rows = max(1, math.ceil(lmap.n / chunks))
    return len(cloudpickle.dumps(as_dask(lmap, rows).dask))


def _table_bytes(lmap: LatentMap) -> int:
    rows = lmap.embeddings
    table = getattr(rows, "table", rows)
    return int(np.prod(table.shape)) * np.dtype(table.dtype).itemsize


def _assert_same_answers(lmap, vecs, client, texts=("chair", "sofa")):
    expected = _quash(vecs).query_many(lmap, list(texts))
    got = _quash(vecs, backend="dask", client=client).query_many(lmap, list(texts))
    for e, g in zip(expected, got, strict=True):
        assert 0 < e.n_matched < lmap.n  # a meaningful comparison
        np.testing.assert_array_equal(g.mask, e.mask)
        np.testing.assert_array_equal(g.scores, e.scores)


@pytest.mark.parametrize("all_points", [True, False])
def test_openscene_graph_does_not_grow_with_the_table(tmp_path, all_points):
    """The repro of the walkthrough: the graph held OpenScene's whole ``feat`` (as an
    array inside ``IndexedRows``, or the plain array with ``all_points=False``)."""
    sizes, tables = [], []
    for k, (n, d) in enumerate([(600, 16), (6000, 128)]):
        pt, _ = _openscene(tmp_path / f"s{k}", n, d, seed=k)
        lmap = read_map(pt, all_points=all_points)
        tables.append(_table_bytes(lmap))
        sizes.append(_graph_bytes(lmap))
    assert tables[1] > 50 * tables[0] and tables[1] > 900_000
    # the same graph: only the numbers and the paths in it differ
    assert abs(sizes[1] - sizes[0]) < 512, (sizes, tables)
    assert sizes[1] < 16_000


def test_openscene_rows_pickle_as_references_and_read_the_same(tmp_path):
    from quash_plugins.adapters._rows import MaskedRows

    pt, _ = _openscene(tmp_path, 700, 24)
    lmap = read_map(pt)
    rows = lmap.embeddings
    assert isinstance(rows, MaskedRows)
    assert isinstance(rows.table, np.memmap) and isinstance(rows.mask, np.memmap)
    assert str(rows.table.filename) == str(pt)  # the .pt itself, not a copy
    back = pickle.loads(pickle.dumps(rows))
    assert len(pickle.dumps(rows)) < 2_000
    saved = torch.load(pt, weights_only=True)
    expected = np.zeros((700, 24), np.float16)
    expected[saved["mask_full"].numpy()] = saved["feat"].numpy()
    for r in (rows, back):
        np.testing.assert_array_equal(np.asarray(r), expected)
        np.testing.assert_array_equal(r[65:331], expected[65:331])
        np.testing.assert_array_equal(r[[699, 3, 3, 400]], expected[[699, 3, 3, 400]])
    np.testing.assert_array_equal(back.index, rows.index)  # what an export writes


def test_openscene_dask_answers_equal_numpy(tmp_path, client):
    pt, vecs = _openscene(tmp_path, 3000, 32)
    for all_points in (True, False):
        _assert_same_answers(read_map(pt, all_points=all_points), vecs, client)


def test_openlex3d_graph_does_not_grow_and_answers_equal(tmp_path, client):
    pytest.importorskip("open3d")
    from _cf_writers import save_openlex3d

    sizes, tables = [], []
    vecs = _words(32)
    for k, (n, m, d) in enumerate([(500, 10, 32), (5000, 2000, 32)]):
        rng = np.random.default_rng(k)
        labels = rng.integers(0, 3, size=m)
        table = np.stack([vecs[WORDS[j]] for j in labels]) + 0.5 * rng.normal(size=(m, d))
        index = rng.integers(0, m, size=n)
        index[rng.random(n) < 0.05] = -1  # points of no object
        folder = save_openlex3d(
            tmp_path / f"o{k}",
            rng.uniform(-2, 2, size=(n, 3)),
            rng.uniform(0, 1, size=(n, 3)),
            table.astype(np.float32),
            index.astype(np.int64),
        )
        lmap = read_map(folder)
        assert isinstance(lmap.embeddings, IndexedRows)
        assert isinstance(lmap.embeddings.index, np.memmap)  # index.npy by reference too
        tables.append(_table_bytes(lmap))
        sizes.append(_graph_bytes(lmap))
    assert tables[1] > 100 * tables[0]
    assert abs(sizes[1] - sizes[0]) < 512, (sizes, tables)
    _assert_same_answers(lmap, vecs, client)


def test_rows_in_memory_travel_with_their_values():
    """An array no file backs (a ConceptGraphs table) stays as it is: pickled by value."""
    from quash_plugins.adapters._rows import MaskedRows

    table = np.arange(40, dtype=np.float32).reshape(10, 4)
    rows = IndexedRows(table, np.array([3, -1, 9, 0]))
    back = pickle.loads(pickle.dumps(rows))
    np.testing.assert_array_equal(np.asarray(back), np.asarray(rows))
    masked = MaskedRows(table, np.r_[np.ones(10, bool), np.zeros(5, bool)])
    back = pickle.loads(pickle.dumps(masked))
    np.testing.assert_array_equal(np.asarray(back), np.asarray(masked))
    np.testing.assert_array_equal(back.index, np.r_[np.arange(10), [-1] * 5])


def test_tensor_memmaps_read_what_torch_reads(tmp_path):
    from quash_plugins.adapters._torch_zip import tensor_memmaps

    base = torch.randn(100, 8)
    path = tmp_path / "t.pt"
    torch.save(
        {"view": base[10:30], "half": base.half(), "bf16": base.bfloat16(), "t": base.T}, path
    )
    maps = tensor_memmaps(path)
    # a view keeps its storage offset; bfloat16 (no numpy dtype) and a transposed
    # (non-contiguous) tensor are left to torch.load
    assert sorted(maps) == ["half", "view"]
    np.testing.assert_array_equal(maps["view"], base[10:30].numpy())
    np.testing.assert_array_equal(maps["half"], base.half().numpy())
    torch.save(base, tmp_path / "bare.pt")
    np.testing.assert_array_equal(tensor_memmaps(tmp_path / "bare.pt")[""], base.numpy())
    torch.save({"feat": base}, tmp_path / "legacy.pt", _use_new_zipfile_serialization=False)
    assert tensor_memmaps(tmp_path / "legacy.pt") == {}


def test_a_legacy_openscene_file_is_read_in_memory(tmp_path):
    """torch's legacy (non-zip) format cannot be memory-mapped: the table stays in memory
    (and travels in a Dask graph with its values), read as before."""
    pt, _ = _openscene(tmp_path, 200, 8)
    saved = torch.load(pt, weights_only=True)
    legacy = pt.with_name("scene0001_00_1.pt")
    torch.save(saved, legacy, _use_new_zipfile_serialization=False)
    a, b = read_map(pt), read_map(legacy, "openscene")
    assert not isinstance(b.embeddings.table, np.memmap)
    np.testing.assert_array_equal(np.asarray(a.embeddings), np.asarray(b.embeddings))


# ---------------------------------------------------------------------------------------
# The classifiers in the graph


def _training(n: int, d: int, seed: int):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)).astype(np.float32)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = (rng.random(n) < 0.1).astype(int)
    y[:3] = 1
    return X, y


def _fitted(d: int = 384, n: int = 1100):
    """The default config's classifiers: nearest-sample for the first pass, the refined
    svm-rbf (1100 training rows), plus the cosine SVM."""
    X, y = _training(n, d, 0)
    return [
        registry.create("classifiers", "nearest-sample", k=2).fit(X, y),
        registry.create("classifiers", "svm-rbf", C=1.0, backend="numpy").fit(X, y),
        registry.create("classifiers", "svm-cosine", backend="numpy").fit(X, y),
    ]


def _needed_bytes(clf) -> int:
    """The arrays scoring reads: the support vectors or the label vectors."""
    if hasattr(clf, "support_vectors_"):
        return clf.kernel_part_.vectors.nbytes + clf.kernel_part_.coef.nbytes
    return clf.positives_.nbytes + clf.negatives_.nbytes


def test_block_scorer_pickles_only_what_scoring_reads():
    clfs = _fitted()
    scorer = BlockScorer(clfs)
    needed = sum(_needed_bytes(c) for c in clfs)
    size = len(pickle.dumps(scorer))
    assert size < 1.1 * needed + 50_000, (size, needed)
    back = pickle.loads(pickle.dumps(scorer))
    rng = np.random.default_rng(5)
    E = rng.normal(size=(3000, 384)).astype(np.float16)
    E[::7] = 0
    for normalize in (True, False):
        a = scorer.score(E, 0, normalize, {}, threads=1)
        np.testing.assert_array_equal(back.score(E, 0, normalize, {}, threads=1), a)
    # the client's classifiers are untouched: scikit-learn's model and the training set
    assert hasattr(clfs[1], "svc_") and hasattr(clfs[2], "X_fit_")


@pytest.mark.parametrize("name", ["nearest-sample", "svm-rbf", "svm-cosine", "contrast"])
def test_a_classifier_pickles_without_derived_copies(name):
    X, y = _training(600, 64, 1)
    clf = registry.create("classifiers", name, **({"backend": "numpy"} if "svm" in name else {}))
    clf.fit(X, y)
    data = pickle.dumps(clf)
    # the classifier's own pickle keeps scikit-learn's model and the training set, but
    # no derived copy (the label vectors twice more, the SVMs' GEMM columns)
    kept = clf.X_fit_.nbytes if hasattr(clf, "X_fit_") else 0
    kept += clf.svc_.support_vectors_.nbytes if hasattr(clf, "svc_") else 0
    assert len(data) < 1.05 * (_needed_bytes(clf) + kept) + 10_000
    back = pickle.loads(data)
    E = np.random.default_rng(2).normal(size=(500, 64)).astype(np.float32)
    np.testing.assert_array_equal(back.decision_function(E), clf.decision_function(E))
    if name == "svm-rbf":  # scikit-learn's model is kept: the pickle is the classifier
        X64 = X.astype(np.float64)[:50]
        np.testing.assert_array_equal(
            back.svc_.decision_function(X64), clf.svc_.decision_function(X64)
        )
    if "svm" not in name:
        np.testing.assert_array_equal(back.labels_t_, clf.labels_t_)


def test_no_large_graph_warning_for_refined_queries(tmp_path, client):
    """Four refined SVMs (~1100 support vectors at D = 384) over a memory-mapped map:
    the graph was over Dask's 10 MB warning (scikit-learn's float64 model and the GEMM
    columns travelled with each); now it holds the support vectors once."""
    d = 384
    clfs = []
    for seed in range(4):
        X, y = _training(1100, d, seed)
        y = (np.random.default_rng(seed).random(1100) < 0.5).astype(int)  # most are SVs
        clfs.append(registry.create("classifiers", "svm-rbf", backend="numpy").fit(X, y))
    assert sum(len(c.support_vectors_) for c in clfs) > 3500
    rng = np.random.default_rng(9)
    path = tmp_path / "emb.npy"
    np.save(path, rng.normal(size=(4000, d)).astype(np.float16))
    lmap = LatentMap(np.load(path, mmap_mode="r"), normalize=True)
    with warnings.catch_warnings():
        warnings.filterwarnings("error", message="Sending large graph")
        scores, observed = classify_dask(lmap, clfs, chunk_bytes=2**20, client=client)
    ref, ref_obs = classify_local(lmap, clfs, chunk_bytes=2**20)
    np.testing.assert_array_equal(observed, ref_obs)
    for s, r in zip(scores, ref, strict=True):
        np.testing.assert_array_equal(s, r)


def test_a_map_in_memory_is_scattered_not_sent_in_the_graph(tmp_path, client):
    """An NPZ map is read into memory: its rows travelled inside the task graph (Dask's
    "Sending large graph of size 122 MiB" for 2 M rows). They are scattered to the
    workers now, and the graph of a 5 MB map stays under a 1 MB warning threshold; the
    answers equal the in-memory backend's, bit for bit."""
    import dask

    d, n = 64, 20_000
    vecs = _words(d)
    rng = np.random.default_rng(5)
    labels = rng.integers(0, 3, size=n)
    emb = np.stack([vecs[WORDS[k]] for k in labels]) + 0.6 * rng.normal(size=(n, d))
    emb[rng.random(n) < 0.01] = 0  # unobserved rows
    path = tmp_path / "map.npz"
    np.savez(path, embeddings=emb.astype(np.float32))
    lmap = read_map(path)
    assert isinstance(lmap.embeddings, np.ndarray) and lmap.embeddings.nbytes > 5e6
    with (
        dask.config.set({"distributed.admin.large-graph-warning-threshold": "1MB"}),
        warnings.catch_warnings(),
    ):
        warnings.filterwarnings("error", message="Sending large graph")
        _assert_same_answers(lmap, vecs, client)
    x = as_dask(lmap, 4096, client)
    assert x.chunks[0] == as_dask(lmap, 4096).chunks[0]  # the same rows in each chunk
    np.testing.assert_array_equal(x.compute(), lmap.embeddings)
