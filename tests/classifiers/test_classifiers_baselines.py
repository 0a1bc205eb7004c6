"""The peers' rules, each checked against an independent re-implementation of the
published rule (VLMaps, ConceptFusion, LERF, OpenScene), plus display scores and the
threshold knob."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import Quash
from quash_plugins.classifiers import ClassifierParamError
from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError
from quash_plugins.encoders import TableEncoder

D = 32


@pytest.fixture
def world():
    rng = np.random.default_rng(11)
    T = rng.standard_normal((7, D))
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    pos, neg = T[:2], T[2:]
    X = np.concatenate([pos, neg]).astype(np.float32)
    y = np.array([1, 1, 0, 0, 0, 0, 0])
    E = T[rng.integers(0, 7, 4000)] + 0.6 * rng.standard_normal((4000, D))
    E *= rng.uniform(0.1, 4.0, (4000, 1))  # not unit: the rules are on cosines
    return {"X": X, "y": y, "E": E.astype(np.float32), "pos": pos, "neg": neg}


def _cos(E, T):
    En = E / np.linalg.norm(E, axis=1, keepdims=True)
    return En @ T.T


def test_contrast_is_vlmaps_closer_to_query_than_every_negative(world):
    clf = registry.create("classifiers", "contrast").fit(world["X"], world["y"])
    c_pos, c_neg = _cos(world["E"], world["pos"]), _cos(world["E"], world["neg"])
    # closer to a positive than to every single negative, counted negative by negative
    expected = np.zeros(len(world["E"]), bool)
    for p in range(c_pos.shape[1]):
        expected |= np.all(c_pos[:, [p]] > c_neg, axis=1)
    np.testing.assert_array_equal(clf.predict(world["E"]), expected)


def test_label_argmax_is_openscene_argmax_over_the_label_set(world):
    clf = registry.create("classifiers", "label-argmax").fit(world["X"], world["y"])
    labels = np.concatenate([world["pos"], world["neg"]])
    winner = np.argmax(_cos(world["E"], labels), axis=1)
    np.testing.assert_array_equal(clf.predict(world["E"]), winner < len(world["pos"]))
    # display: the two-way softmax of best positive vs best negative (CLIP scale 100)
    s = clf.decision_function(world["E"])
    c = _cos(world["E"], labels)
    best_p, best_n = c[:, :2].max(1), c[:, 2:].max(1)
    soft = np.exp(100 * best_p) / (np.exp(100 * best_p) + np.exp(100 * best_n))
    np.testing.assert_allclose(clf.display_scores(s), soft, atol=1e-4)


def _lerf_reference(E, pos, neg, temperature=10.0):
    """LERF's get_relevancy: per positive, softmax over [pos, neg_i] for each negative,
    keep the negative where the positive's probability is lowest."""
    c = _cos(E, np.concatenate([pos, neg]))
    best = np.zeros(len(E))
    for p in range(len(pos)):
        pairs = np.stack([np.repeat(c[:, [p]], len(neg), 1), c[:, len(pos) :]], axis=-1)
        z = np.exp(temperature * pairs)
        soft = z / z.sum(-1, keepdims=True)  # (N, n_neg, 2)
        worst = np.argmin(soft[..., 0], axis=1)
        best = np.maximum(best, soft[np.arange(len(E)), worst, 0])
    return best


def test_lerf_relevancy_matches_the_published_rule(world):
    clf = registry.create("classifiers", "lerf-relevancy").fit(world["X"], world["y"])
    rel = _lerf_reference(world["E"], world["pos"], world["neg"])
    np.testing.assert_allclose(clf.relevancy(world["E"]), rel, atol=1e-5)
    np.testing.assert_array_equal(clf.predict(world["E"]), rel > 0.5)
    # display is the relevancy itself at the default threshold
    np.testing.assert_allclose(
        clf.display_scores(clf.decision_function(world["E"])), rel, atol=1e-5
    )
    other = registry.create("classifiers", "lerf-relevancy", temperature=3.0, cut=0.7)
    other.fit(world["X"], world["y"])
    rel3 = _lerf_reference(world["E"], world["pos"], world["neg"], 3.0)
    np.testing.assert_array_equal(other.predict(world["E"]), rel3 > 0.7)


def _conceptfusion_reference(E, q, cut=0.6):
    """ConceptFusion's demo: cosine, (s+1)/2, min-max over the map, keep above the cut."""
    s = (_cos(E, q[None])[:, 0] + 1.0) / 2.0
    rel = (s - s.min()) / (s.max() - s.min() + 1e-12)
    return rel, rel > cut


def test_cosine_threshold_relative_is_conceptfusion(world):
    X, y = world["X"][[0, 2, 3]], np.array([1, 0, 0])
    clf = registry.create("classifiers", "cosine-threshold").fit(X, y)
    rel, expected = _conceptfusion_reference(world["E"], world["pos"][0])
    raw = clf.decision_function(world["E"])
    np.testing.assert_allclose(clf.postprocess_scores(raw) + 0.6, rel, atol=1e-5)
    np.testing.assert_array_equal(clf.predict(world["E"]), expected)
    # always highlights something: the best item of any map is kept
    assert clf.predict(world["E"][:50]).any()
    absolute = registry.create("classifiers", "cosine-threshold", mode="absolute", cut=0.3)
    absolute.fit(X, y)
    cos = _cos(world["E"], world["pos"][:1])[:, 0]
    np.testing.assert_array_equal(absolute.predict(world["E"]), cos > 0.3)


def test_relative_threshold_is_map_level_in_the_pipeline(tiny_world):
    """The pipeline min-max normalises over the whole observed map, not per chunk."""
    enc = TableEncoder(file=str(tiny_world["table"]))
    clf = registry.create("classifiers", "cosine-threshold")
    big = Quash(enc, classifier=clf, instances=None).query(tiny_world["map"], "chair")
    small = Quash(enc, classifier=clf, instances=None, chunk_mb=0.001)
    small = small.query(tiny_world["map"], "chair")
    q = tiny_world["T"][tiny_world["words"].index("chair")]
    _, expected = _conceptfusion_reference(tiny_world["E"], q)
    np.testing.assert_array_equal(big.mask, expected)
    np.testing.assert_array_equal(small.mask, expected)


@pytest.mark.parametrize(
    "name",
    ["contrast", "label-argmax", "lerf-relevancy", "cosine-threshold", "svm-rbf", "svm-cosine"],
)
def test_raising_the_threshold_reduces_matches_monotonically(tiny_world, name):
    enc = TableEncoder(file=str(tiny_world["table"]))
    counts, displays, scores = [], [], []
    for t in (-0.4, -0.2, -0.1, 0.0, 0.05, 0.1, 0.2, 0.4):
        quash = Quash(
            enc, classifier=registry.create("classifiers", name), threshold=t, instances=None
        )
        r = quash.query(tiny_world["map"], "sofa")
        d = r.display_scores
        assert ((d >= 0) & (d <= 1)).all(), (t, d.min(), d.max(), np.isnan(d).sum())
        # the display maps the cut to 0.5: matches are exactly the items above one half
        above = r.display_scores > 0.5
        assert (above == r.mask).mean() > 0.99
        counts.append(int(r.mask.sum()))
        displays.append(r.display_scores)
        scores.append(r.scores)
    assert counts == sorted(counts, reverse=True), counts
    assert counts[0] > counts[-1]
    # the threshold moves the cut, not the scores ...
    for s in scores[1:]:
        np.testing.assert_array_equal(s, scores[0])
    # ... so no item's display score rises when the threshold does, and some fall
    for lower, higher in zip(displays, displays[1:]):
        assert (higher <= lower + 1e-6).all(), float((higher - lower).max())
    assert (displays[-1] < displays[0] - 1e-3).any()


@pytest.mark.parametrize(
    "name,params,field",
    [
        ("cosine-threshold", {"mode": "sigmoid"}, "mode"),
        ("cosine-threshold", {"mode": "absolute"}, "cut"),
        ("cosine-threshold", {"cut": 1.5}, "cut"),
        ("lerf-relevancy", {"temperature": 0}, "temperature"),
        ("lerf-relevancy", {"cut": 1.0}, "cut"),
        ("label-argmax", {"logit_scale": -1}, "logit_scale"),
    ],
)
def test_bad_baseline_params_are_rejected(name, params, field, world):
    with pytest.raises(ConfigError, match=field):
        registry.create("classifiers", name, **params)
    # scikit-learn's contract: the constructor stores the value, fit rejects it
    clf = registry.load("classifiers", name)(**params)
    assert {k: clf.get_params()[k] for k in params} == params
    with pytest.raises(ClassifierParamError, match=field):
        clf.fit(world["X"], world["y"])


def test_float16_and_zero_rows(world):
    E = world["E"].copy()
    E[:3] = 0
    for name in ("contrast", "lerf-relevancy", "cosine-threshold", "label-argmax"):
        clf = registry.create("classifiers", name).fit(world["X"], world["y"])
        a = clf.decision_function(E.astype(np.float16))
        b = clf.decision_function(E.astype(np.float16).astype(np.float32))
        np.testing.assert_allclose(a, b, atol=1e-6)
        assert np.isfinite(a).all()


def test_example_configs_load_and_build_their_classifier():
    from pathlib import Path

    from quash_plugins.core.config import QuashConfig

    folder = Path(__file__).resolve().parents[2] / "examples" / "configs"
    files = sorted(folder.glob("*.yaml"))
    assert {f.stem for f in files} >= {"lerf-relevancy", "conceptfusion-relative", "label-argmax"}
    for f in files:
        cfg = QuashConfig.from_yaml(f)
        clf = registry.create("classifiers", cfg.classifier.name, **cfg.classifier.params)
        assert isinstance(clf, registry.load("classifiers", cfg.classifier.name)), f.name
        # every parameter the example sets reaches the classifier unchanged
        params = clf.get_params(deep=False)
        assert {k: params[k] for k in cfg.classifier.params} == cfg.classifier.params, f.name
        if cfg.classifier.name == "lerf-relevancy":
            assert list(cfg.negatives) == ["object", "things", "stuff", "texture"]


def test_nearest_sample_is_the_top_k_cosine_vote():
    """Independent reimplementation: mean of the k best cosines per side, by sorting."""
    rng = np.random.default_rng(3)
    X = rng.normal(size=(9, 12)).astype(np.float32)
    y = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0])
    E = rng.normal(size=(200, 12)).astype(np.float32) * 4.0
    Xn = X / np.linalg.norm(X, axis=1, keepdims=True)
    cos = (E / np.linalg.norm(E, axis=1, keepdims=True)) @ Xn.T
    for k in (1, 2, 3, 7):
        clf = registry.create("classifiers", "nearest-sample", k=k).fit(X, y)
        pos = np.sort(cos[:, :4], axis=1)[:, ::-1][:, : min(k, 4)].mean(axis=1)
        neg = np.sort(cos[:, 4:], axis=1)[:, ::-1][:, : min(k, 5)].mean(axis=1)
        np.testing.assert_allclose(clf.decision_function(E), pos - neg, atol=1e-5)
    one = registry.create("classifiers", "nearest-sample", k=1).fit(X, y)
    contrast = registry.create("classifiers", "contrast").fit(X, y)
    np.testing.assert_allclose(one.decision_function(E), contrast.decision_function(E), atol=1e-6)


@pytest.mark.parametrize("k", [0, -1, 1.5, True, "2"])
def test_nearest_sample_rejects_bad_k(k, world):
    with pytest.raises(ConfigError, match="k must be an integer"):
        registry.create("classifiers", "nearest-sample", k=k)
    clf = registry.create("classifiers", "nearest-sample").set_params(k=k)
    with pytest.raises(ClassifierParamError, match="k must be an integer"):
        clf.fit(world["X"], world["y"])
