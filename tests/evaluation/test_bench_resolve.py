"""benchmarks/bench_resolve.py: descriptions sorted into right, wrong and unresolved, and
each method's answers counted by case.

The encoder is a table of unit vectors built so that every cosine is known: a description
is ``c * label + sqrt(1 - c^2) * its own direction``, orthogonal to every other name.
"""

from __future__ import annotations

import numpy as np
import pytest
from _bench import load_bench

from quash_plugins.encoders import TableEncoder

TAX = {"bed": ["cot"], "sofa": ["couch"], "fridge": [], "chair": []}
NAMES = ["bed", "cot", "sofa", "couch", "fridge", "chair"]


@pytest.fixture(scope="module")
def br():
    return load_bench("bench_resolve")


def _encoder(descriptions: dict[str, dict[str, float]]) -> TableEncoder:
    """Names on the first axes; each description its cosines to names plus a private axis."""
    dim = len(NAMES) + len(descriptions)
    eye = np.eye(dim, dtype=np.float64)
    table = {n: eye[i].tolist() for i, n in enumerate(NAMES)}
    for j, (text, cos) in enumerate(descriptions.items()):
        v = sum(c * eye[NAMES.index(n)] for n, c in cos.items())
        rest = 1.0 - float(np.dot(v, v))
        table[text] = (v + np.sqrt(rest) * eye[len(NAMES) + j]).tolist()
    return TableEncoder(table=table)


DESCRIPTIONS = {
    "somewhere to sleep": {"cot": 0.7},  # right, through a sub-class
    "where to sit": {"couch": 0.6, "chair": 0.3},  # wrong: truth is chair
    "keeps milk cold": {"fridge": 0.45, "bed": 0.2},  # unresolved; leads by 0.25
    "somewhere to nap": {"bed": 0.42, "sofa": 0.38},  # unresolved; leads by 0.04
    "an elephant": {"chair": 0.3},  # absent, unresolved
    "a huge bed for a giant": {"bed": 0.8},  # absent, resolved to a present label
}
TRUTH = {
    "somewhere to sleep": "bed",
    "where to sit": "chair",
    "keeps milk cold": "fridge",
    "somewhere to nap": "bed",
    "an elephant": None,
    "a huge bed for a giant": None,
}


def test_cases_and_the_lead_rule(br):
    enc = _encoder(DESCRIPTIONS)
    res = br.resolve(TRUTH, TAX, enc, None)
    got = {t: (r["to"], r["case"]) for t, r in res.items()}
    assert got == {
        "somewhere to sleep": ("bed", "right"),
        "where to sit": ("sofa", "wrong"),
        "keeps milk cold": (None, "unresolved"),
        "somewhere to nap": (None, "unresolved"),
        "an elephant": (None, "unresolved"),
        "a huge bed for a giant": ("bed", "wrong"),
    }
    assert res["keeps milk cold"]["cosine"] == pytest.approx(0.45, abs=1e-4)
    assert res["keeps milk cold"]["lead"] == pytest.approx(0.25, abs=1e-4)
    c = br.counts(res, present={"bed", "sofa", "chair"})
    assert c == {
        "right": 1,
        "wrong": 1,
        "unresolved": 2,
        "absent": 2,
        "absent_resolved": 1,
        "absent_to_present": 1,
    }
    # the lead rule resolves the description that leads clearly, not the near tie
    led = br.resolve(TRUTH, TAX, enc, None, lead=(0.4, 0.1))
    assert (led["keeps milk cold"]["to"], led["keeps milk cold"]["how"]) == ("fridge", "lead")
    assert led["somewhere to nap"]["to"] is None
    assert br.resolve(TRUTH, TAX, enc, None, lead=(0.5, 0.1))["keeps milk cold"]["to"] is None


def test_answers_are_counted_by_case(br):
    res = br.resolve(TRUTH, TAX, _encoder(DESCRIPTIONS), None)

    def row(f1, n_pred):
        return {"f1": f1, "n_pred": n_pred}

    runs = [
        {
            "configs": [
                {
                    "name": "quash-labels",
                    "per_query": {
                        "somewhere to sleep": row(0.9, 10),
                        "where to sit": row(0.0, 0),
                        "keeps milk cold": row(0.0, 0),
                        "somewhere to nap": row(0.2, 4),
                    },
                },
                {"name": "vlmaps-labels", "per_query": {"keeps milk cold": row(0.3, 7)}},
            ]
        },
        {"configs": [{"name": "quash-labels", "per_query": {"somewhere to sleep": row(0.7, 9)}}]},
    ]
    got = br.by_case(runs, res)
    q = got["quash-labels"]
    assert q["right"] == {"f1": pytest.approx(0.8), "empty": 0, "n": 2}
    assert q["wrong"] == {"f1": 0.0, "empty": 1, "n": 1}
    assert q["unresolved"] == {"f1": pytest.approx(0.1), "empty": 1, "n": 2}
    assert got["vlmaps-labels"]["unresolved"] == {"f1": pytest.approx(0.3), "empty": 0, "n": 1}
    assert got["openscene-labels"]["right"] == {"f1": None, "empty": 0, "n": 0}
