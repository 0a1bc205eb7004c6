"""The zarr results of a config with refinement and the presence check equal query_many's.

On a small make-scene voxel map (real MiniLM, the map's label list) with the shipped
``demo:quash-labels`` (refine + presence): ``query_to_zarr`` must write the masks and
scores of ``Quash.query_many``, an absent object empty, whatever the group size, without
touching the map. The lazy dask arrays stay the first pass and say so.
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

zarr = pytest.importorskip("zarr")
pytest.importorskip("dask")

from quash_plugins import Quash  # noqa: E402
from quash_plugins.engine import query_to_zarr  # noqa: E402
from quash_plugins.engine.lazy_query import (  # noqa: E402
    BYTES_PER_QUERY_ITEM,
    group_size,
)

#: A present class, a class only the taxonomy knows (never in a make-scene map), another.
QUERIES = ["chair", "piano", "table"]
ABSENT = "piano"


def _quash(**overrides):
    return Quash.from_config("demo:quash-labels", cache=None, **overrides)


def _fingerprint(path):
    return hashlib.sha256(path.read_bytes()).hexdigest(), path.stat().st_mtime_ns


@pytest.fixture(scope="module")
def expected(minilm_scene):
    """``query_many``'s answer, with each query set's provenance as it was then."""
    results = _quash().query_many(minilm_scene, QUERIES)
    by = {r.query: r for r in results}
    # the scene is what the test needs: the absent class's first pass matches items
    # (the presence check empties it), the others are found
    assert by[ABSENT].n_matched == 0 and by[ABSENT].presence.startswith("absent")
    assert by["chair"].n_matched > 0 and by["table"].n_matched > 0
    return [(r, r.queryset.to_dict(), r.classifier) for r in results]


def _store(path):
    return zarr.open_group(str(path), mode="r")


@pytest.mark.parametrize("backend", ["numpy", "dask"])
def test_zarr_equals_query_many_with_refine_and_presence(minilm_scene, expected, tmp_path, backend):
    """Bit for bit: one group is the very same computation as query_many (the same
    classifiers in one BlockScorer over the same blocks; the Dask executor scores the same
    blocks as the local one), so any difference is a step applied differently."""
    q = _quash(backend=backend)
    assert q.refine is not None and q.presence is not None
    before = _fingerprint(minilm_scene)
    out = query_to_zarr(q, minilm_scene, QUERIES, tmp_path / "r.zarr")
    assert _fingerprint(minilm_scene) == before  # the input map is untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr"]  # atomic: no temp left
    g = _store(out)
    assert set(g.array_keys()) == {"scores", "masks", "observed"}
    assert g["scores"].dtype == np.float32 and g["masks"].dtype == bool
    n = len(expected[0][0].mask)
    assert g["scores"].shape == g["masks"].shape == (len(QUERIES), n)
    for i, (r, qs, clf) in enumerate(expected):
        np.testing.assert_array_equal(g["masks"][i], r.mask)
        np.testing.assert_array_equal(g["scores"][i], r.scores)
        assert g.attrs["querysets"][i] == qs  # the refine and presence provenance included
        assert g.attrs["classifiers"][i] == clf  # the refined classifier, as QueryResult's
    absent = QUERIES.index(ABSENT)
    assert not g["masks"][absent].any()
    presence = g.attrs["querysets"][absent]["provenance"]["presence"]
    assert presence["checked"] and presence["present"] is False
    assert g.attrs["querysets"][absent]["provenance"]["refine"]["applied"] in (True, False)
    assert g.attrs["queries"] == QUERIES and g.attrs["threshold"] == q.threshold


def test_several_groups_equal_one_group(minilm_scene, expected, tmp_path, monkeypatch):
    """A tiny group bound answers one query per group. Masks are equal; scores to 1e-4:
    a group's first pass stacks fewer classifiers in the GEMM, whose width may change the
    BLAS kernel's rounding in the last bits (seen: 3e-5 after the RBF refit)."""
    q = _quash()
    one = _store(query_to_zarr(q, minilm_scene, QUERIES, tmp_path / "one.zarr"))
    sizes = []
    answer = Quash._answer

    def spy(self, lmap, pending, *args, **kwargs):
        sizes.append(len(pending))
        return answer(self, lmap, pending, *args, **kwargs)

    monkeypatch.setattr(Quash, "_answer", spy)
    many = _store(query_to_zarr(q, minilm_scene, QUERIES, tmp_path / "many.zarr", group_mb=1e-6))
    assert sizes == [1] * len(QUERIES)
    assert many["scores"].chunks[0] == 1 and one["scores"].chunks[0] == len(QUERIES)
    np.testing.assert_array_equal(many["masks"][:], one["masks"][:])
    np.testing.assert_allclose(many["scores"][:], one["scores"][:], atol=1e-4, rtol=0)
    np.testing.assert_array_equal(many["observed"][:], one["observed"][:])
    for i, (r, _, _) in enumerate(expected):
        np.testing.assert_array_equal(many["masks"][i], r.mask)
    assert many.attrs["classifiers"] == one.attrs["classifiers"]
    assert [s["provenance"]["presence"]["present"] for s in many.attrs["querysets"]] == [
        s["provenance"]["presence"]["present"] for s in one.attrs["querysets"]
    ]


def test_group_size_keeps_the_vectors_under_the_bound():
    n = 1000
    per_query = BYTES_PER_QUERY_ITEM * n
    assert group_size(n, 3 * per_query) == 3
    assert group_size(n, 3 * per_query - 1) == 2
    assert group_size(n, 1) == 1  # at least one query per group
    assert group_size(0, 10) >= 1  # an empty map


def test_lazy_arrays_are_the_first_pass_and_say_so(minilm_scene, expected):
    """The dask arrays skip the steps: they warn, and the absent object matches there
    (what the zarr store used to hold); without the steps there is no warning."""
    lazy = _quash().query_many_lazy(minilm_scene, QUERIES)
    assert lazy.skipped == ["refine", "presence"]
    with pytest.warns(UserWarning, match=r"first pass only.*refine and presence.*to_zarr"):
        masks = np.asarray(lazy.masks)
    assert masks[QUERIES.index(ABSENT)].any()  # the presence check is what empties it
    plain = _quash(refine=None, presence=None).query_many_lazy(minilm_scene, QUERIES)
    assert plain.skipped == []
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.asarray(plain.masks)
