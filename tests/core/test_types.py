"""QueryResult's account of the presence check (the CLI table and the viewer use it)."""

from __future__ import annotations

import numpy as np
import pytest

from quash_plugins.core.types import QueryResult, QuerySet


@pytest.mark.parametrize(
    "info, expected",
    [
        (None, "off"),
        ({"checked": False, "why": "the map has no voxel grid"}, "not checked: the map has no"),
        ({"checked": True, "present": True, "kept": 2, "components": 5}, "present (2 of 5"),
        ({"checked": True, "present": False, "components": 0}, "absent: nothing matched"),
        (
            {"checked": True, "present": False, "components": 3, "best_margin": 0.0123},
            "absent: no component won clearly against the other labels (best margins: "
            "grown region +0.012)",
        ),
        (
            {"checked": True, "present": False, "components": 3, "best_margin": None},
            "absent: no component large enough",
        ),
        (
            {"checked": True, "present": False, "components": 128, "best_margin": None}
            | {"largest_component": 5, "min_component": 8},
            "absent: all 128 components are smaller than min_component=8 (largest: 5 items)",
        ),
        (
            {"checked": True, "present": False, "components": 1, "best_margin": None}
            | {"largest_component": 1, "min_component": 8},
            "absent: the only component (1 item) is smaller than min_component=8",
        ),
        (
            {"checked": True, "present": False, "components": 2, "best_margin": None}
            | {"largest_component": 9, "min_component": 8},
            "absent: no component of at least min_component=8 items beat every negative by "
            "flat_margin",
        ),
    ],
)
def test_a_result_says_what_the_presence_check_decided(info, expected):
    prov = {} if info is None else {"presence": info}
    qs = QuerySet("sofa", ["sofa"], ["cushion"], prov)
    result = QueryResult(qs, np.zeros(4, bool), np.zeros(4, np.float32), np.zeros(4, np.float32))
    assert result.presence.startswith(expected), result.presence
    assert result.summary()["presence"] == result.presence
