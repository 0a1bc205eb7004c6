"""The fused CPU pass (engine.classify.BlockScorer): exact against scikit-learn, one GEMM
per block for every query, the map never written, NaN/Inf named, memory bounded by the
chunk size, and the Dask pass scoring the same blocks bit for bit."""

from __future__ import annotations

import threading
import tracemalloc

import numpy as np
import pytest
from sklearn.metrics.pairwise import cosine_similarity

from quash_plugins import registry
from quash_plugins.core import cpu
from quash_plugins.core.cpu import half_to_float
from quash_plugins.core.errors import MapFormatError
from quash_plugins.core.interfaces import Classifier, CosineClassifier
from quash_plugins.core.kernels import CosineExpansion, CosineMargin
from quash_plugins.core.types import LatentMap
from quash_plugins.engine import BlockScorer, classify_local
from quash_plugins.engine.classify import half_cast

D = 24
SPECS = [
    ("svm-rbf", {}),
    ("svm-rbf", {"gamma": 80.0, "C": 10.0}),  # g|s|^2 beyond the fold limit
    ("svm-cosine", {}),
    ("svm-cosine", {"kernel": "linear-cosine"}),
    ("svm-cosine", {"distance": "plain"}),
    ("contrast", {}),
    ("nearest-sample", {"k": 2}),
    ("lerf-relevancy", {}),
    ("cosine-threshold", {}),
    ("cosine-threshold", {"mode": "absolute", "cut": 0.1}),
    ("label-argmax", {}),
    ("label-argmax", {"normalize_text": False, "ties": "earlier", "query_column": 1}),
    ("sklearn", {"estimator": "sklearn.linear_model.LogisticRegression"}),
]


def _text(rng, n=30):
    X = rng.standard_normal((n, D)).astype(np.float32)
    X[:8] += 1.5 * rng.standard_normal(D).astype(np.float32)
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    return X, (np.arange(n) < 8).astype(int)


def _fitted(rng, specs=SPECS):
    X, y = _text(rng)
    out = []
    for name, params in specs:
        clf = registry.create("classifiers", name, **params)
        if name == "label-argmax" and not params.get("normalize_text", True):
            X = X * rng.uniform(0.5, 2.0, (len(X), 1)).astype(np.float32)  # norms kept
        out.append(clf.fit(X, y))
    return out


def _map(rng, n=2501, dtype=np.float32):
    E = rng.standard_normal((n, D)).astype(np.float32)
    E *= rng.uniform(0.05, 3.0, (n, 1)).astype(np.float32)
    E[::7] = 0.0
    return E.astype(dtype)


def _expected(clf, E64: np.ndarray, normalize: bool) -> np.ndarray:
    """Decision values computed independently of the pass, in float64 (scikit-learn's
    SVC for the SVMs and the estimator; the published formulas for the rules)."""
    n = np.linalg.norm(E64, axis=1, keepdims=True)
    U = np.divide(E64, n, out=np.zeros_like(E64), where=n > 0)
    X = U if normalize else E64
    name = clf._who if hasattr(clf, "_who") else ""
    if name == "svm-rbf":
        return clf.svc_.decision_function(X)
    if name == "svm-cosine":
        cos = cosine_similarity(X, clf.X_fit_.astype(np.float64))
        if clf.kernel == "linear-cosine":
            return clf.svc_.decision_function(cos)
        d = np.maximum(1.0 - cos, 0.0)
        return clf.svc_.decision_function(np.exp(-clf.gamma_ * (d**2 if clf._power == 2 else d)))
    if hasattr(clf, "estimator_"):
        return clf.estimator_.decision_function(X)
    P, N = clf.positives_.astype(np.float64), clf.negatives_.astype(np.float64)
    cp, cn = U @ P.T, U @ N.T
    if name == "nearest-sample":
        k = clf.k
        return np.sort(cp, axis=1)[:, -k:].mean(1) - np.sort(cn, axis=1)[:, -k:].mean(1)
    margin = cp.max(1) - cn.max(1)
    if name == "lerf-relevancy":
        return 1.0 / (1.0 + np.exp(-clf.temperature * margin)) - clf.cut
    if name == "cosine-threshold":
        return cp.max(1) - (clf.cut if clf.mode == "absolute" else 0.0)
    if name == "label-argmax" and clf.ties == "earlier":
        before, after = cn[:, : clf.query_column], cn[:, clf.query_column :]
        return np.minimum(cp.max(1) - before.max(1), cp.max(1) - after.max(1))
    return margin


@pytest.fixture(scope="module")
def fitted():
    return _fitted(np.random.default_rng(0))


@pytest.mark.parametrize("dtype", [np.float32, np.float16, np.float64])
@pytest.mark.parametrize("normalize", [False, True])
def test_every_classifier_matches_sklearn(fitted, dtype, normalize):
    E = _map(np.random.default_rng(1), dtype=dtype)
    E.flags.writeable = False  # a read-only map (memmaps): the pass must not write
    got, obs = classify_local(LatentMap(E, normalize=normalize), fitted, block_rows=333)
    E64 = E.astype(np.float64)
    np.testing.assert_array_equal(obs, (E64**2).sum(1) > 0)
    for clf, g in zip(fitted, got):
        ref = _expected(clf, E64, normalize)
        # float16 maps: the rows are exact in float32, so the bound stays 1e-4
        np.testing.assert_allclose(g[obs], ref[obs], atol=1e-4, err_msg=repr(clf))


def test_one_gemm_per_block_for_every_query(fitted, monkeypatch):
    scorer = BlockScorer(fitted, block_rows=500)
    assert scorer.stacked == [0, 1, 2, 3, 4]
    assert [i for i, _, _ in scorer.rules] == list(range(5, 12))
    assert scorer.others == [12]
    assert scorer.W.shape == (D, scorer.width)
    calls = []
    real = np.matmul

    def counting(a, b, *args, **kw):
        if b is scorer.W:
            calls.append(len(a))
        return real(a, b, *args, **kw)

    monkeypatch.setattr(np, "matmul", counting)
    E = _map(np.random.default_rng(2))
    out = scorer.score(E)
    monkeypatch.undo()
    assert calls == [500, 500, 500, 500, 500, 1]  # one GEMM per block, all 13 queries
    alone = [BlockScorer([c]).score(E)[:, 0] for c in fitted]
    for j, a in enumerate(alone):
        np.testing.assert_allclose(out[:, j], a, atol=2e-6)


def test_rbf_bias_is_folded_only_where_exp_cannot_overflow(fitted):
    assert BlockScorer(fitted[:1]).epilogue(False).fold
    assert not BlockScorer(fitted[:2]).epilogue(True).fold  # gamma 80


def test_unit_rows_as_the_stack_defines_them():
    rng = np.random.default_rng(2)
    X, y = _text(rng, 20)
    clf = registry.create("classifiers", "svm-rbf", unit_rows=True).fit(X, y)
    E = _map(rng)
    n = np.linalg.norm(E, axis=1, keepdims=True)
    E = np.divide(E, n, out=np.zeros_like(E), where=n > 0)
    for normalize in (False, True):
        got, obs = classify_local(LatentMap(E, normalize=normalize), [clf], block_rows=100)
        np.testing.assert_allclose(got[0][obs], clf.decision_function(E)[obs], atol=1e-5)


def test_declared_margins_are_the_rules_own_reductions(fitted):
    """A CosineMargin is what the GPU pass runs; it must equal the rule's numpy code."""
    c = np.random.default_rng(3).uniform(-1, 1, (400, 30)).astype(np.float32)
    declared = 0
    for clf in fitted:
        exp = clf.cosine_expansion() if isinstance(clf, CosineClassifier) else None
        if exp is None or exp.margin is None:
            continue
        declared += 1
        np.testing.assert_allclose(exp.margin.apply(c), exp.reduce(c), atol=1e-7)
    assert declared == 6  # every built-in rule but label-argmax with ties 'earlier'


class TopCosine(Classifier):
    """A third-party rule: the cosine with its first training row, through the protocol."""

    def fit(self, X, y):
        self.v_ = np.asarray(X[:1], np.float32)
        return self

    def decision_function(self, E):
        E = np.asarray(E, np.float64)
        n = np.linalg.norm(E, axis=1)
        return np.divide(E @ self.v_[0], n, out=np.zeros(len(E)), where=n > 0)

    def cosine_expansion(self):
        return CosineExpansion(self.v_, lambda c: c[:, 0].copy(), CosineMargin(1))


def test_a_plugin_joins_the_gemm_through_the_protocol(fitted):
    plugin = TopCosine().fit(*_text(np.random.default_rng(4)))
    assert isinstance(plugin, CosineClassifier)
    scorer = BlockScorer([fitted[0], plugin])
    assert scorer.rules == [(1, scorer.stack.width, scorer.stack.width + 1)]
    E = _map(np.random.default_rng(5))
    np.testing.assert_allclose(scorer.score(E)[:, 1], plugin.decision_function(E), atol=1e-6)


def test_a_rule_subclass_with_its_own_decision_is_called_as_it_is(fitted):
    Contrast = registry.load("classifiers", "contrast")

    class Shifted(Contrast):
        def decision_function(self, E):
            return super().decision_function(E) + 5.0

    X, y = _text(np.random.default_rng(6))
    clf = Shifted().fit(X, y)
    assert clf.cosine_expansion() is None
    scorer = BlockScorer([clf])
    assert scorer.others == [0]
    E = _map(np.random.default_rng(7))
    np.testing.assert_allclose(scorer.score(E)[:, 0], clf.decision_function(E), atol=1e-6)


def test_half_to_float_is_exact_for_every_finite_half():
    h = np.arange(65536, dtype=np.uint16).view(np.float16).reshape(-1, 4)
    out = half_to_float(h, np.empty(h.shape, np.float32), step=1000)
    ref = h.astype(np.float32)
    fin = np.isfinite(ref)
    np.testing.assert_array_equal(out[fin], ref[fin])
    assert np.all(np.abs(out[~fin]) >= 2.0**16)  # NaN/Inf land where no finite half is


@pytest.mark.parametrize("cast", ["numpy", "torch"])
@pytest.mark.parametrize("dtype", [np.float32, np.float16])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf_name_the_row(fitted, monkeypatch, cast, dtype, bad):
    if cast == "torch":
        pytest.importorskip("torch")
    monkeypatch.setenv("QUASH_HALF_CAST", "numpy" if cast == "numpy" else "torch")
    assert (half_cast() is None) == (cast == "numpy")
    E = _map(np.random.default_rng(3), dtype=dtype)
    E[1234, 5] = bad
    with pytest.raises(MapFormatError, match="row 1234"):
        classify_local(LatentMap(E, source={"path": "m.npz"}), fitted[:1], block_rows=500)


def test_both_half_casts_give_the_same_bits(fitted, monkeypatch):
    pytest.importorskip("torch")
    E = _map(np.random.default_rng(4), dtype=np.float16)
    out = {}
    for cast in ("numpy", "torch"):
        monkeypatch.setenv("QUASH_HALF_CAST", cast)
        out[cast] = classify_local(LatentMap(E, normalize=True), fitted)[0]
    for a, b in zip(out["numpy"], out["torch"]):
        np.testing.assert_array_equal(a, b)


def test_large_finite_rows_are_not_errors(fitted):
    E = _map(np.random.default_rng(4))
    E[10] = 1e25  # |x|^2 overflows float32
    E16 = _map(np.random.default_rng(4), dtype=np.float16)
    E16[10] = 60000.0  # |x|^2 >= 2**32: the exact check runs and passes
    for M in (E, E16):
        scores, obs = classify_local(LatentMap(M), fitted[:1])
        assert obs[10] and np.isfinite(scores[0]).all()


def test_threads_and_block_order_do_not_change_a_bit(fitted):
    E = _map(np.random.default_rng(5), n=9000, dtype=np.float16)
    one, _ = classify_local(LatentMap(E, normalize=True), fitted, threads=1)
    two, _ = classify_local(LatentMap(E, normalize=True), fitted, threads=3)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


def test_progress_counts_every_row(fitted):
    E = _map(np.random.default_rng(5))
    seen = []
    classify_local(LatentMap(E), fitted[:2], progress=seen.append, block_rows=300)
    assert sum(seen) == len(E) and len(seen) == 9


class Rows:
    """A map that is not an ndarray (like h5py or zarr): every read is a new array."""

    def __init__(self, E):
        self.E, self.shape, self.dtype = E, E.shape, E.dtype

    def __len__(self):
        return len(self.E)

    def __getitem__(self, key):
        return np.array(self.E[key])


@pytest.mark.parametrize("dtype", [np.float16, np.float32])
def test_peak_memory_is_bounded_by_the_chunk_size(fitted, dtype):
    """A 200k x 64 map read through a row reader: the pass holds one chunk as stored,
    the per-thread block buffers and the outputs, never the map."""
    rng = np.random.default_rng(6)
    E = rng.standard_normal((200_000, 64)).astype(dtype)
    X, y = _text(rng)
    X = np.pad(X, ((0, 0), (0, 64 - D)))
    clfs = [registry.create("classifiers", n).fit(X, y) for n in ("svm-rbf", "contrast")]
    chunk = 2 * 2**20
    lmap = LatentMap(Rows(E), normalize=True)
    rows = lmap.chunk_rows(chunk, 64)
    tracemalloc.start()
    try:
        classify_local(lmap, clfs, chunk_bytes=chunk, threads=2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    outputs = len(E) * (4 * len(clfs) + 1)
    map_bytes = E.nbytes
    assert rows * 64 * 4 <= chunk
    # one chunk read as stored, its copy, two workers' block buffers, the outputs
    bound = outputs + 2 * chunk + 2 * 3 * 2048 * 64 * 4 + 2**20
    assert peak < bound < map_bytes + outputs, (peak, bound, map_bytes)


def test_blas_limit_is_reference_counted(monkeypatch):
    entered, exited = [], []

    class Limit:
        def __enter__(self):
            entered.append(1)

        def __exit__(self, *exc):
            exited.append(1)

    monkeypatch.setattr(cpu, "_blas_limit", Limit)
    barrier = threading.Barrier(3)

    def user():
        with cpu.blas_single_thread():
            barrier.wait()  # all three inside at once

    threads = [threading.Thread(target=user) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert entered == [1] and exited == [1]  # set once, restored once, by the last out


def test_dask_threads_score_the_same_blocks_bit_for_bit(fitted):
    pytest.importorskip("dask")
    from quash_plugins.engine import classify_dask

    E = _map(np.random.default_rng(8), n=20_000, dtype=np.float16)
    lmap = LatentMap(E, normalize=True)
    local, obs = classify_local(lmap, fitted, chunk_bytes=2**18)
    remote, robs = classify_dask(lmap, fitted, chunk_bytes=2**18)
    np.testing.assert_array_equal(obs, robs)
    for a, b in zip(local, remote):
        np.testing.assert_array_equal(a, b)


def test_dask_query_many_does_one_gemm_per_block_for_every_query(monkeypatch):
    """Issue 13, item 5: on Dask too, all SVM queries of a batch share one GEMM a block."""
    pytest.importorskip("dask")
    from quash_plugins import Quash
    from quash_plugins.encoders import TableEncoder
    from quash_plugins.engine import dask_executor

    # in this process (the threads scheduler), even if another test left a client behind
    monkeypatch.setattr(dask_executor, "current_client", lambda client=None: None)

    rng = np.random.default_rng(9)
    words = ["chair", "sofa", "table", "other", "background", "nothing"]
    T = rng.normal(size=(len(words), D))
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    E = (T[rng.integers(0, 3, 6000)] + 0.5 * rng.normal(size=(6000, D))).astype(np.float16)
    q = Quash(
        TableEncoder(table=dict(zip(words, T.tolist()))),
        classifier=registry.create("classifiers", "svm-rbf"),
        instances=None,
        backend="dask",
        chunk_mb=0.05,  # several chunks
    )
    widths = []
    real = np.matmul

    def counting(a, b, *args, **kw):
        if getattr(b, "ndim", 0) == 2 and b.shape[0] == D and a.shape[1] == D and len(a) > 1:
            widths.append(b.shape[1])  # a block of map rows (not the one-row zero probe)
        return real(a, b, *args, **kw)

    monkeypatch.setattr(np, "matmul", counting)
    results = q.query_many(LatentMap(E, normalize=True), ["chair", "sofa", "table"])
    monkeypatch.undo()
    from quash_plugins.engine.classify import extra_bytes_per_row

    fitted = [q.fit(r.queryset) for r in results]
    n_sv = sum(len(c.support_vectors_) for c in fitted)
    rows = LatentMap(E).chunk_rows(int(0.05 * 2**20), extra_bytes_per_row(fitted))
    assert rows < 2048  # so every chunk is one block
    assert len(widths) == -(-6000 // rows) > 1  # one GEMM per chunk, not one per query
    assert set(widths) == {n_sv}  # every GEMM holds the three queries' support vectors


def test_the_conformance_kit_catches_an_expansion_that_disagrees():
    """The engine trusts a plugin's expansion: the kit checks it against the plugin's
    own decision_function."""
    from quash_plugins.testing import check_classifier_expansions

    check_classifier_expansions(TopCosine(), None)  # agrees

    class Lying(TopCosine):
        def cosine_expansion(self):
            return CosineExpansion(self.v_, lambda c: c[:, 0] + 0.5, CosineMargin(1))

    with pytest.raises(AssertionError, match="reduce of the cosines must give"):
        check_classifier_expansions(Lying(), None)


def test_dask_scores_lseg_layout_frames_bit_for_bit(fitted, tmp_path, monkeypatch):
    """Per-image features in LSeg's (1, D, h, w) layout are read as transposed views, so
    a chunk of several frames came to a Dask task in Fortran order, and its GEMM rounded
    scores differently from the local pass, which reads C-ordered chunks (up to 2e-7
    apart): Dask and the local pass score the same C-ordered rows."""
    pytest.importorskip("dask")
    from quash_plugins.adapters import read_map
    from quash_plugins.engine import classify_dask, dask_executor

    monkeypatch.setattr(dask_executor, "current_client", lambda client=None: None)
    rng = np.random.default_rng(10)
    for i in range(3):  # three frames: a chunk concatenates them
        np.save(tmp_path / f"f{i}.npy", rng.standard_normal((1, D, 30, 40)).astype(np.float32))
    lmap = read_map(tmp_path, "image-features", colors=False)
    local, obs = classify_local(lmap, fitted)
    remote, robs = classify_dask(lmap, fitted)
    np.testing.assert_array_equal(obs, robs)
    for a, b in zip(local, remote):
        np.testing.assert_array_equal(a, b)
