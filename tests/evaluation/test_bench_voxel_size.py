"""benchmarks/bench_voxel_size.py: its table of means over seeds, and its arguments."""

from __future__ import annotations

import pytest
from _bench import load_bench


@pytest.fixture(scope="module")
def bv():
    return load_bench("bench_voxel_size")


def _rec(seed, size, scenario, f1s, empties=(0, 0, 0)):
    """A run record with F1 per method (QuASH, VLMaps', OpenScene's) in that order."""
    configs = {
        m: {
            "f1": f,
            "recall": f / 2,
            "ap": 0.5,
            "absence": 1.0 if i == 0 else 0.5,
            "present_empty": e,
            "n_present": 10,
        }
        for i, (m, f, e) in enumerate(
            zip(("quash-labels", "vlmaps-labels", "openscene-labels"), f1s, empties)
        )
    }
    return {
        "seed": seed,
        "voxel_size": size,
        "scenario": scenario,
        "items": 1000 + seed,
        "configs": configs,
    }


def test_summary_means_over_seeds_and_ratio_to_the_better_peer(bv):
    recs = [
        _rec(0, 0.05, "closed", (0.8, 0.5, 0.6), (1, 0, 0)),
        _rec(1, 0.05, "closed", (0.6, 0.5, 0.2), (2, 0, 0)),
        _rec(0, 0.2, "open-list", (0.3, 0.4, 0.1)),
    ]
    lines = bv.summary(recs)
    rows = [ln.split("|")[1:-1] for ln in lines[2:]]
    quash_closed = next(
        r for r in rows if r[0].strip() == "closed" and r[3].strip() == "quash-labels"
    )
    assert quash_closed[1].strip() == "0.05 m"
    assert float(quash_closed[4]) == pytest.approx((0.8 + 0.6) / 2)
    # the better peer by mean F1: VLMaps' 0.5 over OpenScene's 0.4
    assert quash_closed[-1].strip() == f"{0.7 / 0.5:.2f}x"
    assert quash_closed[-2].strip() == "3/20"  # present -> empty summed over seeds
    open_quash = next(
        r for r in rows if r[0].strip() == "open-list" and r[3].strip() == "quash-labels"
    )
    assert open_quash[-1].strip() == f"{0.3 / 0.4:.2f}x"
    peers = [r for r in rows if r[3].strip() != "quash-labels"]
    assert all(r[-1].strip() == "" for r in peers)  # the ratio is QuASH's alone
    assert len(rows) == 6


@pytest.mark.parametrize("spec", ["", "0.1,-0.05", "a,b", "0.1,nan"])
def test_bad_voxel_sizes_are_refused(bv, spec):
    with pytest.raises(SystemExit, match="--voxel-sizes"):
        bv.parse_sizes(spec)
    assert bv.parse_sizes("0.05,0.1") == [0.05, 0.1]
