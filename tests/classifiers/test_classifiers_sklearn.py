"""The ``sklearn`` classifier: any scikit-learn estimator by dotted path."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.linear_model import LogisticRegression
from sklearn.neighbors import KNeighborsClassifier

from quash_plugins import Quash
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError
from quash_plugins.encoders import TableEncoder


@pytest.fixture
def data():
    rng = np.random.default_rng(21)
    X = rng.standard_normal((30, 16)).astype(np.float32)
    X[:10] += 2.0
    y = (np.arange(30) < 10).astype(int)
    E = rng.standard_normal((5003, 16)).astype(np.float32) + rng.choice([0.0, 2.0], (5003, 1))
    return X, y, E


def test_knn_by_dotted_path_uses_predict_proba(data):
    X, y, E = data
    clf = registry.create(
        "classifiers",
        "sklearn",
        estimator="sklearn.neighbors.KNeighborsClassifier",
        params={"n_neighbors": 3},
        block_rows=1000,
    ).fit(X, y)
    ref = KNeighborsClassifier(n_neighbors=3).fit(X, y).predict_proba(E)[:, 1]
    scores = clf.decision_function(E)
    assert clf.uses_proba_
    np.testing.assert_allclose(scores, ref - 0.5, atol=1e-6)
    np.testing.assert_array_equal(clf.predict(E), ref > 0.5)
    # display is the probability itself at the default threshold
    np.testing.assert_allclose(clf.display_scores(scores), ref, atol=1e-6)


def test_decision_function_estimator_keeps_its_sign(data):
    X, y, E = data
    clf = registry.create(
        "classifiers",
        "sklearn",
        estimator="sklearn.linear_model.LogisticRegression",
        params={"C": 0.5},
    ).fit(X, y)
    ref = LogisticRegression(C=0.5).fit(X, y).decision_function(E)
    np.testing.assert_allclose(clf.decision_function(E), ref, rtol=1e-5, atol=1e-5)
    assert clf.decision_function(X[:10]).mean() > 0 > clf.decision_function(X[10:]).mean()


def test_svc_through_the_pipeline(tiny_world):
    from sklearn.svm import SVC

    enc = TableEncoder(file=str(tiny_world["table"]))
    clf = registry.create(
        "classifiers",
        "sklearn",
        estimator="sklearn.svm.SVC",
        params={"kernel": "rbf", "class_weight": "balanced"},
    )
    quash = Quash(enc, classifier=clf, instances=None)
    r = quash.query(tiny_world["map"], "chair")
    X, y, _ = quash.training_set(r.queryset)
    ref = SVC(kernel="rbf", class_weight="balanced").fit(X, y).decision_function(tiny_world["E"])
    np.testing.assert_allclose(r.scores, ref, atol=1e-5)
    np.testing.assert_array_equal(r.mask, ref > 0)
    label = tiny_world["label_names"].index("chair")
    assert r.mask[tiny_world["labels"] == label].mean() > 0.5


@pytest.mark.parametrize(
    "params,needle",
    [
        ({"estimator": "KNeighborsClassifier"}, "dotted path"),
        ({"estimator": "sklearn.neighbors.NoSuchThing"}, "defines no 'NoSuchThing'"),
        ({"estimator": "nonexistent_pkg_xyz.Model"}, "no module 'nonexistent_pkg_xyz'"),
        ({"estimator": "sklearn.cluster.KMeans"}, "neither decision_function nor predict_proba"),
        ({"estimator": "sklearn.linear_model.LinearRegression"}, "neither"),
        ({"estimator": "numpy.ndarray"}, "not a scikit-learn estimator"),
        ({"estimator": "sklearn.svm.SVC", "params": {"kernal": "rbf"}}, "kernal"),
        ({"estimator": "sklearn.svm.SVC", "params": ["rbf"]}, "mapping"),
        ({"block_rows": 0}, "block_rows"),
    ],
)
def test_bad_estimators_are_rejected_clearly(params, needle):
    with pytest.raises(ConfigError, match=needle):
        registry.create("classifiers", "sklearn", **params)


def test_estimator_module_is_not_imported_before_its_name_is_checked(tmp_path, monkeypatch):
    """A config names a module; its top-level code must not run for a wrong name."""
    marker = tmp_path / "imported"
    (tmp_path / "quash_probe_mod.py").write_text(
        f"open({str(marker)!r}, 'w').close()\n"
        "def Boom():\n    pass\n"
        "class NotAnEstimator:\n    pass\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    for path, needle in (
        ("quash_probe_mod.Missing", "defines no 'Missing'"),
        ("quash_probe_mod:Boom", "is a function, not a class"),
        ("quash_probe_mod.Boom()", "dotted path"),
        ("quash_probe_mod..Boom", "dotted path"),
        ("quash_probe_mod:Boom:Boom", "more than one ':'"),
        ("os.path.join; import this", "dotted path"),
    ):
        with pytest.raises(ConfigError, match=needle):
            registry.create("classifiers", "sklearn", estimator=path)
        assert not marker.exists(), path
    with pytest.raises(ConfigError, match="not a scikit-learn estimator"):
        registry.create("classifiers", "sklearn", estimator="quash_probe_mod:NotAnEstimator")
    assert marker.exists()  # a plausible class name is imported, then checked


def test_estimator_colon_form():
    clf = registry.create("classifiers", "sklearn", estimator="sklearn.svm:SVC")
    assert clf.estimator == "sklearn.svm:SVC"
