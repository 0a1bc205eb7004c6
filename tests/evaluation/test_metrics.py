"""Metrics against an independent set-based computation; absence and exclusion rules."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.evaluation.metrics import absence_score, macro_mean, query_metrics, valid_items


def _reference(mask, truth, valid):
    pred = {i for i, (m, v) in enumerate(zip(mask, valid)) if m and v}
    gt = {i for i, (t, v) in enumerate(zip(truth, valid)) if t and v}
    tp, fp, fn = len(pred & gt), len(pred - gt), len(gt - pred)
    p = tp / (tp + fp) if tp + fp else (1.0 if not gt else 0.0)
    r = tp / (tp + fn) if tp + fn else (1.0 if not pred else 0.0)
    f = 2 * p * r / (p + r) if p + r else 0.0
    iou = tp / len(pred | gt) if pred | gt else 1.0
    return tp, fp, fn, p, r, f, iou


@pytest.mark.parametrize("seed", range(6))
def test_query_metrics_match_set_computation(seed):
    rng = np.random.default_rng(seed)
    n = 200
    mask, truth = rng.random(n) < 0.3, rng.random(n) < 0.2
    valid = rng.random(n) < 0.8
    m = query_metrics(mask, truth, valid)
    tp, fp, fn, p, r, f, iou = _reference(mask, truth, valid)
    assert (m["tp"], m["fp"], m["fn"]) == (tp, fp, fn)
    assert m["precision"] == pytest.approx(p)
    assert m["recall"] == pytest.approx(r)
    assert m["f1"] == pytest.approx(f)
    assert m["iou"] == pytest.approx(iou)


def test_empty_denominators():
    """The documented rules (docs/evaluation.md): nothing predicted and nothing true is a
    perfect answer (precision 1, recall 1, so F1 1, IoU 1)."""
    none = np.zeros(4, bool)
    m = query_metrics(none, none)
    assert (m["tp"], m["fp"], m["fn"], m["n_true"], m["n_pred"]) == (0, 0, 0, 0, 0)
    assert (m["precision"], m["recall"], m["f1"], m["iou"]) == (1.0, 1.0, 1.0, 1.0)
    assert m == query_metrics(none, none, valid=np.ones(4, bool))
    # and the independent set computation agrees
    assert _reference(none, none, np.ones(4, bool))[3:] == (1.0, 1.0, 1.0, 1.0)
    # all items excluded: the same empty-set answer, whatever the mask says
    m = query_metrics(np.ones(4, bool), np.ones(4, bool), valid=np.zeros(4, bool))
    assert (m["precision"], m["recall"], m["f1"], m["iou"]) == (1.0, 1.0, 1.0, 1.0)
    m = query_metrics(np.array([1, 0, 0, 0], bool), none)
    assert m["precision"] == 0.0 and m["recall"] == 0.0
    m = query_metrics(none, np.array([1, 0, 0, 0], bool))
    assert m["precision"] == 0.0 and m["recall"] == 0.0 and m["iou"] == 0.0


def test_macro_mean_is_unweighted():
    per = {
        "a": {"precision": 1.0, "recall": 0.0, "f1": 0.0, "iou": 0.0},
        "b": {"precision": 0.0, "recall": 1.0, "f1": 0.5, "iou": 1.0},
    }
    assert macro_mean(per) == {
        **{"precision": 0.5, "recall": 0.5, "f1": 0.25, "iou": 0.5},
        **{"ap": None, "inv_rank": None},  # no query has a ranking metric: null, still there
    }


def test_excluded_and_unlabelled_items_are_ignored():
    labels = np.array([0, 0, 1, 2, -1])
    valid = valid_items(labels, ["chair", "void", "sofa"], exclude=["void"])
    assert valid.tolist() == [True, True, False, True, False]
    mask = np.ones(5, bool)  # predicts everything, including void and unlabelled items
    m = query_metrics(mask, labels == 0, valid)
    assert (m["tp"], m["fp"]) == (2, 1)  # only the sofa counts as a false positive


def test_absence_score_and_tolerance():
    masks = {
        "piano": np.zeros(5, bool),
        "car": np.array([1, 0, 0, 0, 0], bool),
        "bath": np.array([1, 1, 0, 0, 0], bool),
    }
    s = absence_score(masks)
    assert s["score"] == pytest.approx(1 / 3)
    assert s["per_query"]["car"] == {"matched": 1, "empty": False}
    assert absence_score(masks, empty_tolerance=1)["score"] == pytest.approx(2 / 3)
    valid = np.array([False, True, True, True, True])
    assert absence_score(masks, valid)["score"] == pytest.approx(2 / 3)
    assert absence_score({})["score"] is None
