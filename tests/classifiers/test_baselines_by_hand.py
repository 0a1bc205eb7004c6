"""The paper's formulas and the peers' published rules on examples small enough to work out
by hand (2-D and 3-D vectors; every expected number below was computed on paper from the
formula it names, not by the code under test).

The paper (Pekkanen et al., QuASH, Sec. IV-B) writes the two state-of-the-art rules as

- a threshold on the cosine distance, ``d_cos(e, e_q) < theta`` (ConceptFusion's family);
- ``1_{e_q}(argmin_{x in {e_q, e_qbar}} d_cos(e, x))``: closer to the query than to the
  complement (VLMaps, LERF, ...), with "other" as the complement in its baseline (Sec. V-A).
"""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import Quash
from quash_plugins.core import registry
from quash_plugins.core.shipped import find_shipped
from quash_plugins.core.types import LatentMap
from quash_plugins.encoders import TableEncoder

R5 = np.sqrt(5.0)


def _fit(name, pos, neg, **params):
    X = np.array([*pos, *neg], dtype=np.float32)
    y = np.array([1] * len(pos) + [0] * len(neg))
    return registry.create("classifiers", name, **params).fit(X, y)


# items: (2, 1) nearer the query (1, 0); (1, 3) nearer "other" (0, 1); (3, 3) a tie;
# (-1, 0.2) nearer "other". Cosines with q: 2/sqrt5, 1/sqrt10, 1/sqrt2, -1/sqrt(1.04).
ITEMS = np.array([[2, 1], [1, 3], [3, 3], [-1, 0.2]], dtype=np.float32)
Q, OTHER = [1.0, 0.0], [0.0, 1.0]


def test_paper_eq1_closer_to_the_query_than_to_other():
    clf = _fit("contrast", [Q], [OTHER])
    # cos(e, q) - cos(e, other), item by item
    expected = [2 / R5 - 1 / R5, 1 / np.sqrt(10) - 3 / np.sqrt(10), 0.0, -1 / 1.0198 - 0.2 / 1.0198]
    np.testing.assert_allclose(clf.decision_function(ITEMS), expected, atol=1e-4)
    # argmin of the cosine distance is the query for the first item only; a tie is no match
    np.testing.assert_array_equal(clf.predict(ITEMS), [1, 0, 0, 0])


def test_vlmaps_argmax_sends_a_tie_to_the_query_column():
    # numpy.argmax over [query, other] returns the first column on a tie: VLMaps matches it
    clf = _fit("label-argmax", [Q], [OTHER], ties="earlier")
    np.testing.assert_array_equal(clf.predict(ITEMS), [1, 0, 1, 0])


def test_paper_cosine_distance_threshold_is_the_absolute_cut():
    # d_cos < theta  <=>  cos > 1 - theta; theta = 0.2: cos > 0.8
    # cosines with q = (1, 0): 2/sqrt5 = 0.894, 3/sqrt10 = 0.949, 1/sqrt2 = 0.707, 0.316
    E = np.array([[2, 1], [3, 1], [1, 1], [1, 3]], dtype=np.float32)
    clf = _fit("cosine-threshold", [Q], [OTHER], mode="absolute", cut=0.8)
    np.testing.assert_array_equal(clf.predict(E), [1, 1, 0, 0])
    expected = [2 / R5 - 0.8, 3 / np.sqrt(10) - 0.8, 1 / np.sqrt(2) - 0.8, 1 / np.sqrt(10) - 0.8]
    np.testing.assert_allclose(clf.decision_function(E), expected, atol=1e-5)


def test_conceptfusion_relative_threshold_by_hand():
    # cosines 1, 0, -1, 1/sqrt2 -> (s + 1) / 2 = 1, 0.5, 0, 0.85355; min 0, max 1
    E = np.array([[1, 0], [0, 1], [-1, 0], [1, 1]], dtype=np.float32)
    clf = _fit("cosine-threshold", [Q], [OTHER])  # relative, cut 0.6: ConceptFusion's demo
    rel = clf.postprocess_scores(clf.decision_function(E)) + 0.6
    np.testing.assert_allclose(rel, [1.0, 0.5, 0.0, 0.853553], atol=1e-5)
    np.testing.assert_array_equal(clf.predict(E), [1, 0, 0, 1])
    # map-level: without the (-1, 0) item the minimum is 0.5, so (0, 1) -> 0 and
    # (1, 1) -> (0.853553 - 0.5) / 0.5 = 0.707107
    rel3 = clf.postprocess_scores(clf.decision_function(E[[0, 1, 3]])) + 0.6
    np.testing.assert_allclose(rel3, [1.0, 0.0, 0.707107], atol=1e-5)


def test_lerf_relevancy_by_hand():
    # LERF: min over the negatives of softmax(10 [q.x, n.x])[q], pairwise.
    # q = (1, 0); negatives n1 = (0, 1), n2 = (0.6, 0.8).
    # a = (1, 0):     pairs (1, 0) and (1, 0.6)    -> min(s(10), s(4))   = s(4)   = 0.982014
    # b = (0.6, 0.8): pairs (0.6, 0.8), (0.6, 1)   -> min(s(-2), s(-4))  = s(-4)  = 0.017986
    # c = (0.8, 0.6): pairs (0.8, 0.6), (0.8, 0.96) -> min(s(2), s(-1.6)) = s(-1.6) = 0.167982
    # with s(z) = e^z / (e^z + 1), the two-way softmax of a pair
    E = np.array([[1, 0], [0.6, 0.8], [0.8, 0.6]], dtype=np.float32)
    clf = _fit("lerf-relevancy", [Q], [[0, 1], [0.6, 0.8]])
    np.testing.assert_allclose(clf.relevancy(E), [0.982014, 0.017986, 0.167982], atol=1e-5)
    np.testing.assert_array_equal(clf.predict(E), [1, 0, 0])  # relevancy above 0.5


def test_openscene_label_argmax_by_hand():
    # labels chair (1,0,0), table (0,1,0), sofa (0,0,1): each item takes its largest cosine
    labels = np.eye(3)
    E = np.array([[0.9, 0.5, 0.1], [0.2, 0.3, 0.25], [0.1, 0.1, 0.9]], dtype=np.float32)
    for q, expected in ((0, [1, 0, 0]), (1, [0, 1, 0]), (2, [0, 0, 1])):
        clf = _fit("label-argmax", [labels[q]], [labels[i] for i in range(3) if i != q])
        np.testing.assert_array_equal(clf.predict(E), expected)


def test_vlmaps_index_map_keeps_the_template_mean_unnormalised():
    """VLMaps averages each category's unit template embeddings and does not re-normalise
    the mean. Two templates: "chair" gives (1, 0) and (0, 1), mean (0.5, 0.5) (norm 0.707);
    "other" gives (0.6, 0.8) twice, mean (0.6, 0.8). Scores x . mean:

    | item          | chair | other | VLMaps    | normalised chair (0.707, 0.707) |
    | (0.8, 0.6)    | 0.70  | 0.96  | other     | 0.990 > 0.96: chair              |
    | (1, 0)        | 0.50  | 0.60  | other     | 0.707 > 0.60: chair              |
    | (0, 1)        | 0.50  | 0.80  | other     | 0.707 < 0.80: other              |
    | (0.71, -0.71) | 0.00  | -0.14 | chair     | chair                            |
    """
    enc = TableEncoder(
        table={
            "A chair": [1, 0],
            "B chair": [0, 1],
            "A other": [0.6, 0.8],
            "B other": [0.6, 0.8],
        }
    )
    E = np.array([[0.8, 0.6], [1, 0], [0, 1], [0.7071, -0.7071]], dtype=np.float32)
    lmap = LatentMap(E)
    templates = ["A {}", "B {}"]

    def mask(classifier, normalize):
        quash = Quash(
            enc,
            heuristic="none",
            classifier=classifier,
            negatives=["other"],
            prompt_templates={"mode": "mean", "templates": templates, "normalize": normalize},
            instances=None,
            cache=None,
        )
        return quash.query(lmap, "chair").mask.tolist()

    vlmaps = {"name": "label-argmax", "normalize_text": False, "ties": "earlier"}
    assert mask(vlmaps, False) == [False, False, False, True]
    # the paper's baseline compares cosines, where the mean's norm does not count
    assert mask("contrast", True) == [True, True, False, True]
    assert mask("contrast", False) == [True, True, False, True]


def test_the_zero_vector_antonym_is_a_cosine_above_zero():
    # the paper's "zero vector" complement (Table IV): cos(e, 0) is taken as 0, so an item
    # matches when its cosine with the query is positive
    enc = TableEncoder(table={"chair": [1, 0]})
    E = np.array([[0.5, 3], [-0.1, 1], [2, -1], [-1, -1]], dtype=np.float32)
    quash = Quash(
        enc, heuristic="none", classifier="contrast", negatives=["<zero>"], instances=None
    )
    r = quash.query(LatentMap(E), "chair")
    assert r.mask.tolist() == [True, False, True, False]
    # the score is the cosine with the query itself: 0.5/sqrt(9.25), -0.1/sqrt(1.01), ...
    np.testing.assert_allclose(
        r.scores, [0.5 / np.sqrt(9.25), -0.1 / np.sqrt(1.01), 2 / R5, -1 / np.sqrt(2)], atol=1e-5
    )


@pytest.mark.parametrize(
    "name,negatives,classifier",
    [
        # LERF: the canonical phrases, temperature 10, relevancy cut 0.5
        (
            "lerf",
            ["object", "things", "stuff", "texture"],
            {"name": "lerf-relevancy", "temperature": 10.0, "cut": 0.5},
        ),
        # ConceptFusion: (s + 1) / 2, min-max over the map, 0.6
        ("conceptfusion", None, {"name": "cosine-threshold", "mode": "relative", "cut": 0.6}),
        # VLMaps' index_map: argmax over [query, "other"], template means kept as they are
        (
            "vlmaps",
            ["other"],
            {"name": "label-argmax", "normalize_text": False, "ties": "earlier"},
        ),
    ],
)
def test_shipped_peer_configs_carry_the_published_settings(name, negatives, classifier):
    cfg = find_shipped(f"demo:{name}").data()
    assert cfg["heuristic"] == "none"  # the query alone
    assert cfg["classifier"] == classifier
    if negatives is not None:
        assert cfg["negatives"] == negatives
    if name == "vlmaps":
        assert cfg["prompt_templates"] == {
            "mode": "mean",
            "templates": "vlmaps-or-default",  # VLMaps' own list when it is installed
            "normalize": False,
        }
