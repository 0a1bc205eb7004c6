"""scikit-learn's contract for every registered classifier, and the SVMs against SVC.

scikit-learn's own ``parametrize_with_checks`` runs over every classifier the registry
knows (the paper's SVMs and every peer's rule). A check a decision rule cannot pass by
design is declared by the classifier's ``expected_failed_checks()`` with its reason and
runs as a strict xfail: if it starts passing, the declaration fails the suite.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from scipy import sparse
from sklearn.base import clone
from sklearn.datasets import make_blobs
from sklearn.exceptions import NotFittedError
from sklearn.svm import SVC
from sklearn.utils.estimator_checks import check_estimator, parametrize_with_checks

from quash_plugins.classifiers import ContrastClassifier
from quash_plugins.core import registry
from quash_plugins.core.interfaces import Classifier
from quash_plugins.testing import check_classifier, expected_failed_checks

NAMES = registry.available("classifiers")


def _build(name: str) -> Classifier:
    """The registered classifier with its conformance parameters, as the kit builds it."""
    cls = registry.load("classifiers", name)
    factory = getattr(cls, "conformance_params", None)
    params = dict(factory(Path(tempfile.mkdtemp()))) if callable(factory) else {}
    return registry.create("classifiers", name, **params)


CLASSIFIERS = [_build(name) for name in NAMES]


def test_every_builtin_classifier_is_checked():
    builtin = {
        "svm-rbf",
        "svm-cosine",
        "sklearn",
        "contrast",
        "cosine-threshold",
        "label-argmax",
        "lerf-relevancy",
        "nearest-sample",
    }
    assert builtin <= set(NAMES)
    assert len(CLASSIFIERS) == len(NAMES)


# ConceptFusion's absolute mode declares no expected failure: it must pass every check.
ABSOLUTE = registry.create("classifiers", "cosine-threshold", mode="absolute", cut=0.25)


@parametrize_with_checks(
    [*CLASSIFIERS, ABSOLUTE], expected_failed_checks=expected_failed_checks, xfail_strict=True
)
def test_sklearn_check(estimator, check):
    check(estimator)


def _results(est) -> dict[str, set[str]]:
    """check name -> the statuses of its runs (a check may run with several settings)."""
    out: dict[str, set[str]] = {}
    for r in check_estimator(est, on_fail=None, on_skip=None):
        out.setdefault(r["check_name"], set()).add(r["status"])
    return out


# SVC takes sample_weight in fit; QuASH's classifiers take none (class_weight weights
# the positives against the negatives), so scikit-learn does not run these on them.
SAMPLE_WEIGHT_CHECKS = {
    "check_all_zero_sample_weights_error",
    "check_sample_weight_equivalence_on_dense_data",
    "check_sample_weight_equivalence_on_sparse_data",
    "check_sample_weights_list",
    "check_sample_weights_not_an_array",
    "check_sample_weights_not_overwritten",
    "check_sample_weights_pandas_series",
    "check_sample_weights_shape",
}


@pytest.mark.parametrize("name", ["svm-rbf", "svm-cosine"])
def test_svms_pass_every_check_svc_passes(name):
    svc = _results(SVC())
    ours = _results(registry.create("classifiers", name))
    svc_passes = {c for c, s in svc.items() if s == {"passed"}}
    assert len(svc_passes) >= 40, "scikit-learn ran fewer checks on SVC than expected"
    # every check SVC runs, ours runs too, except the sample_weight ones (no such argument)
    assert set(svc) - set(ours) == SAMPLE_WEIGHT_CHECKS & set(svc)
    # where SVC passes, ours passes (every run of the check)
    worse = sorted(c for c in svc_passes if c in ours and ours[c] != {"passed"})
    assert not worse, f"{name} fails checks SVC passes: {worse}"
    # and ours fails nothing at all, including the binary-only check SVC does not run
    assert all(s <= {"passed", "skipped"} for s in ours.values()), ours
    assert ours["check_classifier_not_supporting_multiclass"] == {"passed"}


@pytest.mark.parametrize("labels", [["one", "two"], [-1, 1], [0, 1]])
def test_svm_rbf_equals_svc_on_scikit_learns_data(labels):
    """The data of check_classifiers_train; any two labels, the larger one positive."""
    X, y = make_blobs(n_samples=300, centers=2, random_state=0, cluster_std=2.5)
    y = np.take(labels, y)
    ours = registry.create("classifiers", "svm-rbf", backend="numpy").fit(X, y)
    ref = SVC().fit(X, y)
    np.testing.assert_array_equal(ours.classes_, ref.classes_)
    np.testing.assert_allclose(ours.decision_function(X), ref.decision_function(X), atol=1e-4)
    np.testing.assert_array_equal(ours.predict(X), ref.predict(X))
    assert ours.n_features_in_ == ref.n_features_in_ == 2


def test_quash_labels_keep_their_meaning():
    """y = 1 for positives: classes_ is [0, 1] and predict gives 1 where the score is > 0."""
    rng = np.random.default_rng(0)
    X = rng.normal(size=(20, 8)).astype(np.float32)
    X[:6] += 3.0
    y = (np.arange(20) < 6).astype(int)
    for clf in CLASSIFIERS:
        fitted = clone(clf).fit(X, y)
        np.testing.assert_array_equal(fitted.classes_, [0, 1])
        s = np.asarray(fitted.postprocess_scores(fitted.decision_function(X)))
        np.testing.assert_array_equal(fitted.predict(X), (s > 0).astype(int))


@pytest.mark.parametrize("clf", CLASSIFIERS, ids=NAMES)
def test_map_input_errors_are_clear(clf):
    rng = np.random.default_rng(1)
    X = rng.normal(size=(12, 6))
    y = np.array([1] * 4 + [0] * 8)
    E = rng.normal(size=(50, 6))
    with pytest.raises(NotFittedError, match=r"call fit\(X, y\)"):
        clone(clf).decision_function(E)
    fitted = clone(clf).fit(X, y)
    assert fitted.n_features_in_ == 6
    bad = E.copy()
    bad[37, 2] = np.inf
    with pytest.raises(ValueError, match="NaN or infinity.*row 37"):
        fitted.decision_function(bad)
    bad[37, 2] = np.nan
    with pytest.raises(ValueError, match="NaN or infinity.*row 37"):
        fitted.decision_function(bad)
    with pytest.raises(TypeError, match=r"sparse input is not supported.*toarray\(\)"):
        fitted.decision_function(sparse.csr_matrix(E))
    with pytest.raises(TypeError, match=r"sparse input is not supported.*toarray\(\)"):
        clone(clf).fit(sparse.csr_matrix(X), y)
    with pytest.raises(ValueError, match="Complex data not supported"):
        fitted.decision_function(E + 1j)
    with pytest.raises(ValueError, match="X has 5 features, but .* expecting 6 features"):
        fitted.decision_function(E[:, :5])
    with pytest.raises(ValueError, match="one class"):
        clone(clf).fit(X, np.ones(12, int))
    with pytest.raises(ValueError, match="Only binary classification is supported"):
        clone(clf).fit(X, np.arange(12) % 3)


class _ValidatesInInit(ContrastClassifier):
    """A third-party classifier that breaks the contract: it validates in __init__."""

    def __init__(self, scale: float = 1.0) -> None:
        if scale <= 0:
            raise ValueError("scale must be positive")
        self.scale = scale


class _StaleDeclaration(ContrastClassifier):
    def expected_failed_checks(self) -> dict[str, str]:
        return {"check_estimators_unfitted": "claimed, but contrast passes it"}


class _NoReason(ContrastClassifier):
    def expected_failed_checks(self) -> dict[str, str]:
        return {"check_classifiers_train": " "}


def test_the_kit_runs_scikit_learns_checks_and_can_fail(tmp_path):
    check_classifier(ContrastClassifier(), tmp_path / "ok")
    with pytest.raises(AssertionError, match="check_do_not_raise_errors_in_init_or_set_params"):
        check_classifier(_ValidatesInInit(), tmp_path / "init")
    with pytest.raises(AssertionError, match=r"check_estimators_unfitted \(passes\)"):
        check_classifier(_StaleDeclaration(), tmp_path / "stale")
    with pytest.raises(AssertionError, match="'check_classifiers_train' needs a reason"):
        check_classifier(_NoReason(), tmp_path / "reason")
