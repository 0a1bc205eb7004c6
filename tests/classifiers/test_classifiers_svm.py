"""svm-rbf and svm-cosine: parity with scikit-learn's decision_function, speed, params."""

from __future__ import annotations

import pickle
import time

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.exceptions import NotFittedError
from sklearn.metrics.pairwise import cosine_similarity

from quash_plugins.classifiers import ClassifierParamError, CosineSvmClassifier, RbfSvmClassifier
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError
from quash_plugins.core.kernels import stack_expansions

D = 48


def _text_set(rng, d=D, n=40, n_pos=12):
    X = rng.standard_normal((n, d)).astype(np.float32)
    X[:n_pos] += 1.5 * rng.standard_normal(d).astype(np.float32)  # positives share a direction
    X /= np.linalg.norm(X, axis=1, keepdims=True)
    y = (np.arange(n) < n_pos).astype(int)
    return X, y


def _map(rng, X, n=3001, d=D):
    """Non-unit rows near the training set, plus zero rows and far rows."""
    idx = rng.integers(0, len(X), n)
    E = X[idx] + 0.3 * rng.standard_normal((n, d), dtype=np.float32)
    E *= rng.uniform(0.2, 3.0, (n, 1)).astype(np.float32)
    E[:5] = 0.0
    E[5:10] = 5 * rng.standard_normal((5, d))
    return E.astype(np.float32)


def _sklearn_reference(clf, E):
    """scikit-learn's decision_function, with the kernel matrix built independently."""
    E = np.asarray(E, dtype=np.float64)
    if isinstance(clf, RbfSvmClassifier):
        return clf.svc_.decision_function(E)
    cos = cosine_similarity(E, clf.X_fit_.astype(np.float64))  # zero rows -> 0
    if clf.kernel == "linear-cosine":
        K = cos
    else:
        d = np.maximum(1.0 - cos, 0.0)
        K = np.exp(-clf.gamma_ * (d**2 if clf.distance == "squared" else d))
    return clf.svc_.decision_function(K)


KERNELS = [
    ("svm-rbf", {}),
    ("svm-rbf", {"gamma": 2.5, "C": 3.0, "class_weight": "balanced"}),
    ("svm-rbf", {"gamma": "auto"}),
    ("svm-cosine", {"kernel": "rbf-cosine"}),
    ("svm-cosine", {"kernel": "rbf-cosine", "distance": "plain", "gamma": 4.0}),
    ("svm-cosine", {"kernel": "linear-cosine", "class_weight": {0: 1.0, 1: 2.0}}),
]


@pytest.mark.parametrize("backend", ["numpy", "torch"])
@pytest.mark.parametrize("name,params", KERNELS)
def test_parity_with_sklearn_every_kernel(name, params, backend):
    rng = np.random.default_rng(3)
    X, y = _text_set(rng)
    E = _map(rng, X)
    # odd block sizes put chunk boundaries everywhere; 1 row per block is the extreme
    # (torch pays a per-call overhead, so its smallest block is larger)
    for block_rows in (None, 7 if backend == "numpy" else 257, 1000):
        clf = registry.create(
            "classifiers", name, backend=backend, device="cpu", block_rows=block_rows, **params
        ).fit(X, y)
        assert clf.backend_ == backend
        ref = _sklearn_reference(clf, E)
        got = clf.decision_function(E)
        assert got.dtype == np.float32 and got.shape == (len(E),)
        np.testing.assert_allclose(got, ref, atol=1e-4, rtol=0)
        assert (clf.predict(E) == (ref > 0)).mean() > 0.999
    # float16 input, up-cast block by block: equal to sklearn on the same float16 values
    E16 = E.astype(np.float16)
    ref16 = _sklearn_reference(clf, E16.astype(np.float32))
    np.testing.assert_allclose(clf.decision_function(E16), ref16, atol=1e-4, rtol=0)


def test_unit_rows_shortcut_matches_on_unit_maps():
    rng = np.random.default_rng(4)
    X, y = _text_set(rng)
    E = _map(rng, X)[10:]
    E /= np.linalg.norm(E, axis=1, keepdims=True)
    for clf in (RbfSvmClassifier(unit_rows=True), CosineSvmClassifier(unit_rows=True)):
        clf.fit(X, y)
        np.testing.assert_allclose(
            clf.decision_function(E), _sklearn_reference(clf, E), atol=1e-4, rtol=0
        )


def test_stacked_queries_share_one_pass_and_match_each_alone():
    rng = np.random.default_rng(5)
    X, y = _text_set(rng)
    E = _map(rng, X)
    fitted = [
        RbfSvmClassifier().fit(X, y),
        CosineSvmClassifier().fit(X, np.roll(y, 7)),
        CosineSvmClassifier(kernel="linear-cosine").fit(X, y),
        RbfSvmClassifier(gamma=0.3).fit(X, np.roll(y, 13)),
        CosineSvmClassifier(distance="plain").fit(X, y),
    ]
    stack, idx = stack_expansions([c.kernel_expansion() for c in fitted])
    assert idx == [0, 1, 2, 3, 4]
    assert stack.width == sum(c.working_set_width_ for c in fitted)
    out = stack.evaluate(E)
    for j, i in enumerate(idx):
        np.testing.assert_allclose(out[:, j], _sklearn_reference(fitted[i], E), atol=1e-4)


def test_pipeline_query_many_uses_the_stack(tiny_world, monkeypatch):
    from quash_plugins import Quash
    from quash_plugins.core import kernels as _kernels
    from quash_plugins.encoders import TableEncoder

    calls = []
    original = _kernels.StackEpilogue.apply
    monkeypatch.setattr(
        _kernels.StackEpilogue,
        "apply",
        lambda self, G, *a: (
            calls.append((len(self.stack.parts), G.shape[1])) or original(self, G, *a)
        ),
    )
    quash = Quash(
        TableEncoder(file=str(tiny_world["table"])), classifier=RbfSvmClassifier(), instances=None
    )
    results = quash.query_many(tiny_world["map"], ["chair", "sofa", "table"])
    # one stacked GEMM per block for the three queries: every epilogue sees all three
    # queries' support vectors side by side
    n_sv = sum(len(quash.fit(r.queryset).support_vectors_) for r in results)
    assert calls and set(calls) == {(3, n_sv)}
    for r in results:
        alone = quash.fit(r.queryset).svc_.decision_function(tiny_world["E"].astype(np.float64))
        np.testing.assert_allclose(r.scores, alone, atol=1e-4)


def test_registry_create_fit_on_64_texts_and_classify_200k_x_512():
    rng = np.random.default_rng(6)
    X, y = _text_set(rng, d=512, n=64, n_pos=20)
    E = _map(rng, X, n=200_000, d=512)
    for name in ("svm-rbf", "svm-cosine"):
        clf = registry.create("classifiers", name).fit(X, y)
        t0 = time.perf_counter()
        scores = clf.decision_function(E)
        t_ours = time.perf_counter() - t0
        assert scores.shape == (200_000,)
        sub = E[::100]  # scikit-learn on a 2,000-row subsample (it is slow)
        t0 = time.perf_counter()
        ref = _sklearn_reference(clf, sub)
        t_sk = (time.perf_counter() - t0) * 100
        np.testing.assert_allclose(scores[::100], ref, atol=1e-4)
        # generous: the benchmark measures the real ratio (tens of times)
        assert t_ours < t_sk, (name, t_ours, t_sk)


@pytest.mark.parametrize(
    "name,params,field",
    [
        ("svm-rbf", {"gamma": "bogus"}, "gamma"),
        ("svm-rbf", {"gamma": -1.0}, "gamma"),
        ("svm-rbf", {"C": 0}, "C"),
        ("svm-rbf", {"class_weight": {2: 1.0}}, "class_weight"),
        ("svm-rbf", {"backend": "cupy"}, "backend"),
        ("svm-rbf", {"device": "tpu"}, "device"),
        ("svm-rbf", {"backend": "numpy", "device": "cuda"}, "cuda"),
        ("svm-rbf", {"working_set_mb": 0}, "working_set_mb"),
        ("svm-rbf", {"block_rows": 0}, "block_rows"),
        ("svm-cosine", {"gamma": "1.5"}, "gamma"),
        ("svm-cosine", {"kernel": "poly"}, "kernel"),
        ("svm-cosine", {"distance": "manhattan"}, "distance"),
        ("svm-cosine", {"kernel": "linear-cosine", "gamma": 2.0}, "gamma"),
        ("svm-cosine", {"kernel": "linear-cosine", "distance": "plain"}, "distance"),
    ],
)
def test_bad_params_are_rejected(name, params, field):
    # a config fails when it builds the classifier, before any model is loaded
    with pytest.raises(ConfigError, match=field):
        registry.create("classifiers", name, **params)
    # scikit-learn's contract: the constructor stores the value unchanged, fit rejects it
    cls = registry.load("classifiers", name)
    clf = cls(**params)
    assert {k: clf.get_params()[k] for k in params} == params
    X, y = _text_set(np.random.default_rng(0))
    with pytest.raises(ClassifierParamError, match=field):
        clf.fit(X, y)
    assert not hasattr(clf, "n_features_in_"), "a rejected fit must leave no fitted state"
    with pytest.raises(ConfigError, match="does not accept"):
        registry.create("classifiers", name, kernel_size=3)


def test_set_params_is_validated_at_fit():
    rng = np.random.default_rng(7)
    X, y = _text_set(rng)
    clf = RbfSvmClassifier().set_params(gamma="oops")
    with pytest.raises(ClassifierParamError, match="gamma"):
        clf.fit(X, y)


def test_clone_pickle_and_unfitted():
    rng = np.random.default_rng(8)
    X, y = _text_set(rng)
    E = _map(rng, X)
    clf = CosineSvmClassifier(gamma=3.0, backend="torch", device="cpu")
    assert clone(clf).get_params() == clf.get_params()
    with pytest.raises(NotFittedError, match=r"svm-cosine: .*call fit\(X, y\)"):
        clf.decision_function(E)
    with pytest.raises(NotFittedError, match="not fitted"):
        clf.predict(E)
    clf.fit(X, y)
    before = clf.decision_function(E)  # builds torch state, which must not be pickled
    again = pickle.loads(pickle.dumps(clf))
    np.testing.assert_allclose(again.decision_function(E), before, atol=1e-6)
    with pytest.raises(ValueError, match=f"X has 10 features, but .* expecting {D} features"):
        clf.decision_function(E[:, :10])


def test_working_set_budget_bounds_block_rows():
    rng = np.random.default_rng(9)
    X, y = _text_set(rng)
    clf = RbfSvmClassifier(working_set_mb=0.05).fit(X, y)
    per_row = 4 * D + 4 * clf.working_set_width_ + 4 + 8
    assert clf.stack_.block_rows * per_row <= 0.05 * 2**20
    assert clf.working_set_width_ == len(clf.support_vectors_)
    E = _map(rng, X)
    np.testing.assert_allclose(clf.decision_function(E), _sklearn_reference(clf, E), atol=1e-4)


def test_peak_memory_stays_within_the_working_set_budget(monkeypatch):
    import tracemalloc

    monkeypatch.setenv("QUASH_CLASSIFY_THREADS", "2")
    rng = np.random.default_rng(10)
    X, y = _text_set(rng, d=256, n=40)
    E = rng.standard_normal((60_000, 256)).astype(np.float16)  # up-cast block by block
    clf = RbfSvmClassifier(working_set_mb=2.0, backend="numpy").fit(X, y)
    clf.decision_function(E[:100])
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    out = clf.decision_function(E)
    peak = tracemalloc.get_traced_memory()[1] - base - out.nbytes
    tracemalloc.stop()
    assert peak <= 1.2 * 2.0 * 2**20, peak / 2**20
    assert E.nbytes * 2 > 10 * 2.0 * 2**20  # a whole up-cast copy would blow the budget


def test_cuda_without_a_gpu_is_a_clear_error_and_auto_falls_back_to_numpy():
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(12)
    X, y = _text_set(rng)
    assert RbfSvmClassifier().fit(X, y).backend_ in ("numpy", "torch")
    if torch.cuda.is_available():  # pragma: no cover - no GPU on the CI machine
        assert RbfSvmClassifier(device="cuda").fit(X, y).device_ == "cuda"
        return
    from quash_plugins.core.errors import QuashError

    with pytest.raises(QuashError, match="CUDA"):
        RbfSvmClassifier(backend="torch", device="cuda").fit(X, y)
    assert RbfSvmClassifier(backend="auto").fit(X, y).backend_ == "numpy"


@pytest.mark.parametrize("device", ["mps", "cuda:1", "CUDA:0"])
def test_every_config_device_builds_the_svms(device):
    """The config passes its `device` to the SVMs: every device the config accepts must
    build them (mps and cuda:N were refused by the SVMs' own, shorter list)."""
    from quash_plugins import Quash

    table = {"chair": [1, 0], "other": [0, 1], "background": [1, 1], "nothing": [1, -1]}
    for name in ("svm-rbf", "svm-cosine"):
        q = Quash.from_config(
            {
                "classifier": name,
                "device": device,
                "cache": False,
                "encoder": {"name": "table", "table": table},
            }  # fmt: skip
        )
        assert q.classifier.device == device.lower() and q.device == device.lower()
    X, y = np.eye(4, dtype=np.float32), np.array([1, 0, 0, 0])
    assert RbfSvmClassifier(device="mps").fit(X, y).device_ == "cpu"  # no Apple-GPU path
