"""The presence check: an object that is there is kept, specks and absent objects go.

The maps are built so the answer is known: a 27-item "bed" block and lone "sofa" specks
whose embeddings sit near their own word (hashed 32-d text vectors).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from _eval_table import table_for, vec

from quash_plugins import LatentMap, Quash
from quash_plugins.core.config import QuashConfig
from quash_plugins.core.errors import ConfigError
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.core.presence_text import presence_words
from quash_plugins.core.types import FrameInfo
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine.presence import PresenceOptions, map_mean, presence_check
from quash_plugins.engine.topology import MapTopology
from quash_plugins.engine.training import training_set
from quash_plugins.heuristics import TaxonomyHeuristic

TAX = {"bed": ["bunk bed", "cot"], "sofa": ["futon", "settee"], "chair": ["armchair"]}


def _encoder():
    names = {n for k, v in TAX.items() for n in (k, *v)} | {"other", "background", "nothing"}
    return TableEncoder(table=table_for(names))


def _rows(name, n, rng, noise=0.3):
    E = np.asarray(vec(name)) + noise * rng.standard_normal((n, 32))
    return E / np.linalg.norm(E, axis=1, keepdims=True)


def _object_map(kind="voxels", n_specks=30, seed=0):
    """27 bed items in a 3x3x3 block at the origin, lone sofa specks 2 cells apart."""
    rng = np.random.default_rng(seed)
    block = [(x, y, z) for x in range(3) for y in range(3) for z in range(3)]
    specks = [(10 + 2 * (i % 10), 10 + 2 * (i // 10), 0) for i in range(n_specks)]
    grid = np.asarray(block + specks)
    E = np.concatenate([_rows("bed", 27, rng), _rows("sofa", n_specks, rng)]).astype(np.float32)
    labels = np.r_[np.zeros(27, int), np.ones(n_specks, int)]
    common = dict(labels=labels, label_names=["bed", "sofa"])
    if kind == "voxels":
        return LatentMap(E, kind="voxels", grid_index=grid, voxel_size=0.1, **common)
    return LatentMap(
        E, kind="points", positions=(grid * 0.1).astype(np.float32), voxel_size=0.1, **common
    )


def _training(query):
    """The query set (taxonomy, every other label a negative group) and its training data."""
    enc = _encoder()
    qs = (
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all")
        .expand(query, ExpansionContext(encoder=enc))
        .with_negatives(["other"])
    )
    X, y, _ = training_set(enc, qs)
    return qs, X, y


def _run(m, mask, query="bed", candidates=None, training=_training, **opts):
    """presence_check on map ``m`` with the query's training set (``training(query)``:
    the query set, X, y) and these options."""
    qs, X, y = training(query)
    E = np.asarray(m.embeddings)
    return presence_check(
        mask,
        X,
        y,
        PresenceOptions(**opts),
        MapTopology(m),
        map_mean(m, lambda i: E[i]),
        lambda i: E[i],
        groups=qs.provenance["negative_groups"],
        candidates=candidates,
    )


def _check(m, mask, query="bed", **opts):
    # the grown and core rules are tested alone; the support rule and the label-name
    # reading have their own tests
    opts.setdefault("support_margin", None)
    opts.setdefault("label_name", False)
    return _run(m, mask, query, **opts)


@pytest.mark.parametrize("kind", ["voxels", "points"])
def test_the_object_is_kept_and_specks_are_dropped(kind):
    m = _object_map(kind)
    mask = np.zeros(m.n, bool)
    mask[:27] = True  # the bed
    mask[27:33] = True  # six sofa specks that matched by noise
    keep, info = _check(m, mask)
    assert keep[:27].all() and not keep[27:].any()
    assert info["present"] and info["components"] == 7 and info["kept"] == 1
    assert info["largest_kept"] == 27 and info["kept_items"] == 27
    # only specks matched: the bed query is absent
    keep, info = _check(m, np.r_[np.zeros(27, bool), mask[27:]])
    assert not keep.any() and info["present"] is False
    # and its words say why: every component is too small to weigh
    largest = info["largest_component"]
    assert largest < info["min_component"] == 8
    assert presence_words({"presence": info}) == (
        "absent: all 6 components are smaller than min_component=8 "
        f"(largest: {largest} item{'' if largest == 1 else 's'})"
    )
    # gate mode keeps the whole mask when any component passes
    keep, _ = _check(m, mask, mode="gate")
    assert np.array_equal(keep, mask)


def test_the_size_floor_and_the_margins():
    m = _object_map()
    mask = np.zeros(m.n, bool)
    mask[:27] = True
    assert not _check(m, mask, min_component=28)[0].any()
    keep, info = _check(m, mask, core_margin=None)
    win = info["best_margin"]  # the grown region's margin
    assert win > 0 and keep[:27].all()
    # present when the grown region wins by more than `margin`, not when by less
    assert not _check(m, mask, margin=win + 1e-3, core_margin=None)[0].any()
    assert _check(m, mask, margin=win - 1e-3, core_margin=None)[0][:27].all()
    # the core (the component's own items) must beat margin + size_margin / sqrt(size)
    _, info = _check(m, mask, margin=9.0, size_margin=0.0)
    core = info["best_core_margin"]
    assert core is not None and core > 0
    size_margin = 0.5 * core * np.sqrt(27)  # takes half of the core's win
    just_above = core - size_margin / np.sqrt(27) - 1e-3
    k, i = _check(m, mask, margin=9.0, size_margin=size_margin, core_margin=just_above)
    assert k[:27].all() and i["best_core_margin"] == pytest.approx(core / 2, abs=1e-3)
    k, _ = _check(m, mask, margin=9.0, size_margin=size_margin, core_margin=just_above + 2e-3)
    assert not k.any()


def test_one_decision_per_query_then_a_looser_keep_margin():
    """A present query keeps its weaker components too (above keep_margin); an absent one
    keeps nothing however many components come close."""
    m = _object_map()
    mask = np.zeros(m.n, bool)
    mask[:27] = True
    _, info = _check(m, mask, core_margin=None)
    win = info["best_margin"]
    # with the bed present, a keep margin below the bed's lets it stay; above, it goes
    assert _check(m, mask, margin=win - 0.01, keep_margin=win - 0.005, core_margin=None)[0].any()
    assert not _check(m, mask, margin=win - 0.01, keep_margin=win + 0.005, core_margin=None)[
        0
    ].any()


def test_a_sofa_block_is_not_a_bed():
    """The mean of the grown region decides: a whole sofa matched for 'bed' goes."""
    rng = np.random.default_rng(1)
    grid = np.asarray([(x, y, z) for x in range(3) for y in range(3) for z in range(3)])
    m = LatentMap(_rows("sofa", 27, rng).astype(np.float32), kind="voxels", grid_index=grid)
    keep, info = _check(m, np.ones(27, bool))
    assert not keep.any() and info["best_margin"] < 0


def test_pixel_maps_are_checked_per_frame():
    rng = np.random.default_rng(2)
    # frame a: a 4x4 bed patch in an 8x8 image of sofa; frame b: all sofa
    E = np.concatenate([_rows("sofa", 64, rng), _rows("sofa", 64, rng)]).astype(np.float32)
    patch = np.zeros((8, 8), bool)
    patch[2:6, 2:6] = True
    E[:64][patch.reshape(-1)] = _rows("bed", 16, rng)
    m = LatentMap(E, kind="pixels", frames=[FrameInfo("a", 8, 8, 0), FrameInfo("b", 8, 8, 64)])
    mask = np.zeros(128, bool)
    mask[:64] = patch.reshape(-1)
    mask[64 + 9] = mask[64 + 30] = True  # two noise pixels in frame b
    keep, info = _check(m, mask)
    assert info["components"] == 3 and keep[:64].sum() == 16 and not keep[64:].any()


def test_options_are_validated_with_the_key_and_the_fix():
    with pytest.raises(ConfigError, match="min_compnent.*Did you mean 'min_component'"):
        PresenceOptions.parse({"min_compnent": 3})
    with pytest.raises(ConfigError, match="mode"):
        PresenceOptions.parse({"mode": "maybe"})
    with pytest.raises(ConfigError, match="dilate must be in"):
        PresenceOptions.parse({"dilate": 9})
    with pytest.raises(ConfigError, match="numbers expected"):
        PresenceOptions.parse({"margin": "big"})
    assert PresenceOptions.parse({"grow": None}).grow is None
    with pytest.raises(ConfigError, match="grow_steps must be >= 0"):
        PresenceOptions.parse({"grow_steps": -1})
    with pytest.raises(ConfigError, match="label_name must be true or false"):
        PresenceOptions.parse({"label_name": "yes"})
    with pytest.raises(ConfigError, match="presence"):
        Quash(_encoder(), presence={"bogus": 1})
    cfg = QuashConfig.from_dict({"presence": True})
    assert cfg.presence == {}
    assert QuashConfig.from_dict({"presence": None}).presence is None


def test_the_pipeline_returns_empty_for_an_absent_label():
    m = _object_map()
    q = Quash(
        _encoder(),
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"),
        presence={},
        instances=False,
    )
    bed, chair, sofa = q.query_many(m, ["bed", "chair", "sofa"])
    assert bed.mask[:27].sum() > 15 and not bed.mask[27:].any()
    assert bed.queryset.provenance["presence"]["present"] is True
    assert not chair.mask.any() and chair.queryset.provenance["presence"]["present"] is False
    # the sofa specks are single items: below the size floor, so the sofa is reported absent
    assert not sofa.mask.any()
    # dropped items rank below every kept one, and below the threshold
    assert bed.scores[~bed.mask].max() < bed.scores[bed.mask].min()
    assert (chair.scores <= q.threshold).all()
    assert "presence" in bed.timings


def test_growth_adds_connected_items_only_after_refinement():
    """Hysteresis growth: kept components grow through refined scores above `grow`."""
    rng = np.random.default_rng(3)
    bed = [(x, y, z) for x in range(6) for y in range(6) for z in range(3)]
    sofa = [(x + 20, y, z) for x in range(10) for y in range(10) for z in range(3)]
    E = np.concatenate([_rows("bed", len(bed), rng, 0.6), _rows("sofa", len(sofa), rng, 0.6)])
    m = LatentMap(E.astype(np.float32), kind="voxels", grid_index=np.asarray(bed + sofa))
    common = dict(heuristic=TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"), instances=False)
    # the grown region decides here (core_margin off: with this much noise the sofa's
    # selected items alone look bed-like)
    unchecked = Quash(_encoder(), refine={}, **common).query(m, "bed")
    off = {"core_margin": None, "support_margin": None}
    plain = Quash(_encoder(), refine={}, presence={**off, "grow": None}, **common).query(m, "bed")
    grown = Quash(_encoder(), refine={}, presence={**off, "grow": -1.0}, **common).query(m, "bed")
    assert plain.queryset.provenance["refine"]["applied"]
    # the check drops the sofa's false matches and keeps the bed's component
    assert unchecked.mask[108:].any() and not plain.mask[108:].any()
    assert plain.mask[:108].sum() > 50
    # growth adds bed items connected to what was kept, never a sofa item
    added = grown.mask & ~plain.mask
    assert (grown.mask >= plain.mask).all() and added.any() and not grown.mask[108:].any()
    assert grown.scores[added].max() < grown.scores[plain.mask].min()
    assert (grown.scores[added] > 0).all()
    assert grown.queryset.provenance["presence"]["grown_items"] == int(grown.mask.sum())
    # without refinement nothing grows
    first = Quash(_encoder(), presence={**off, "grow": -1.0}, **common).query(m, "bed")
    assert "grown_items" not in first.queryset.provenance["presence"]


def test_a_map_without_neighbourhoods_skips_the_check_and_says_so():
    m = LatentMap(_rows("bed", 5, np.random.default_rng(4)).astype(np.float32))
    r = Quash(_encoder(), TaxonomyHeuristic(taxonomy=TAX), presence={}, instances=False).query(
        m, "bed"
    )
    assert r.queryset.provenance["presence"]["checked"] is False
    assert "no voxel grid, positions or frames" in r.queryset.provenance["presence"]["why"]
    assert r.mask.all()


@pytest.mark.parametrize("section", ["presence", "refine"])
def test_the_config_help_states_the_real_defaults(section):
    """The help of the ``presence``/``refine`` keys (docs/config.md is generated from it)
    names every option with the default its dataclass really has."""
    import dataclasses

    from quash_plugins.core.config import QuashConfig
    from quash_plugins.engine.presence import PresenceOptions
    from quash_plugins.engine.refine import RefineOptions

    options = {"presence": PresenceOptions, "refine": RefineOptions}[section]
    field = {f.name: f for f in dataclasses.fields(QuashConfig)}[section]
    help_text = field.metadata["help"]
    for f in dataclasses.fields(options):
        default = "null" if f.default is None else f.default
        default = str(default).lower() if isinstance(default, bool) else default
        assert re.search(rf"\b{f.name}: {re.escape(str(default))}\b", help_text), (f.name, default)


def _small_object_on_a_support(seed=5):
    """A 6x6 'sofa' slab and, on it, a 2x2x2 object that reads as a bed leaning towards
    a chair: its grown region is mostly sofa, its own items are near the chair (and a
    background wall far away)."""
    rng = np.random.default_rng(seed)
    slab = [(x, y, 0) for x in range(6) for y in range(6)]
    small = [(x, y, z) for x in (2, 3) for y in (2, 3) for z in (1, 2)]
    lean = np.asarray(vec("bed")) + 0.9 * np.asarray(vec("chair"))
    obj = lean + 0.05 * rng.standard_normal((len(small), 32))
    obj /= np.linalg.norm(obj, axis=1, keepdims=True)
    # far away, a wall of background so the map's mean is not the sofa's
    wall = [(20 + x, 0, z) for x in range(12) for z in range(12)]
    E = np.concatenate(
        [_rows("sofa", len(slab), rng, 0.05), obj, _rows("background", len(wall), rng, 0.05)]
    ).astype(np.float32)
    return LatentMap(E, kind="voxels", grid_index=np.asarray(slab + small + wall), voxel_size=0.1)


def _centred_cosines(m, items, X):
    """The cosines of the text rows ``X`` to the mean of ``items``, both sides centred
    (the map's mean row, the text rows' mean), computed here from the definition."""

    def unit(a):
        return a / np.linalg.norm(a, axis=-1, keepdims=True)

    E = unit(np.asarray(m.embeddings, np.float64))
    mean = unit(E[items].mean(axis=0) - E.mean(axis=0))
    return unit(X - X.mean(axis=0)) @ mean


def _margins_by_hand(m, items, query="bed"):
    """The centred margins of the query against each label group on a set of items,
    computed here from the definition (positives: mean of the 2 best cosines; a group:
    the mean of its 2 best)."""
    qs, X, y = _training(query)
    c = _centred_cosines(m, items, X)
    pos = np.sort(c[y == 1])[-2:].mean()
    neg = c[y == 0]
    out, start = {}, 0
    groups = [*qs.provenance["negative_groups"]]
    groups.append(len(neg) - sum(groups))
    for size in groups:
        if size:
            out[qs.negatives[start]] = pos - np.sort(neg[start : start + size])[-2:].mean()
        start += size
    return out


def test_the_competitor_an_absent_query_lost_to_is_named():
    """The bed block matched for the absent "chair": the record names the label group
    the best component loses most to, found here from the margins by hand, and the
    decision's words say it."""
    m = _object_map()
    block = np.r_[np.ones(27, bool), np.zeros(len(m.embeddings) - 27, bool)]
    keep, info = _check(m, block, query="chair")
    assert not keep.any()
    by_hand = _margins_by_hand(m, np.flatnonzero(block), query="chair")
    qs = _training("chair")[0]
    assert qs.negatives[info["rival_negative"]] == min(by_hand, key=by_hand.get) == "bed"

    # through the pipeline: a threshold that matches every item puts the bed block
    # before the check, and the record carries the competitor's name
    q = Quash(
        _encoder(),
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"),
        presence={},
        threshold=-10.0,
        instances=False,
    )
    chair = q.query_many(m, ["chair"])[0]
    assert not chair.mask.any()
    assert chair.queryset.provenance["presence"]["rival"] == "bed"
    assert "closest competitor: 'bed'" in chair.presence
    # what the check dropped is kept for the viewer: here every item had matched
    assert chair.rejected is not None and chair.rejected.all()
    assert Quash(_encoder(), instances=False).query(m, "bed").rejected is None  # no check


def test_a_small_object_on_its_support_is_judged_against_the_support():
    """support_margin: the core against the label that wins the grown region. A small
    object whose grown region is its support, and whose own items are close to a third
    label, is emptied by the grown and core checks and found by this one; the support
    itself, matched whole, stays absent."""
    m = _small_object_on_a_support()
    obj = np.arange(36, 44)
    mask = np.zeros(m.n, bool)
    mask[obj] = True
    grown = _margins_by_hand(m, MapTopology(m).region(obj, 1))
    core = _margins_by_hand(m, obj)
    support = min(grown, key=grown.get)
    assert support == "sofa"
    # the old rule: the grown region and the core (against every label) both lose
    assert min(grown.values()) < 0.05
    assert min(core.values()) - 0.3 / np.sqrt(8) < 0.12
    old, info = _check(m, mask, support_margin=None)
    assert not old.any() and info["present"] is False and "best_support_margin" not in info
    # against the support the core wins clearly
    expected = core["sofa"] - 0.3 / np.sqrt(8)
    assert expected > 0.1
    keep, info = _check(m, mask, support_margin=expected - 1e-3)
    assert keep[obj].all() and not keep[:36].any() and info["present"]
    assert info["best_support_margin"] == pytest.approx(expected, abs=1e-3)
    assert not _check(m, mask, support_margin=expected + 1e-3)[0].any()
    # the slab matched for "bed": its grown region's winner is the sofa, and so is its core's
    slab = np.zeros(m.n, bool)
    slab[:36] = True
    assert not _check(m, slab, support_margin=0.0)[0].any()


# ------------------------------------------------------------- the label-name reading
TAX_NAMES = {
    "sofa": ["settee", "divan"],
    "cushion": ["seat cushion", "bolster"],
    "bed": ["bunk bed", "cot"],
}


def _names_encoder():
    names = {n for k, v in TAX_NAMES.items() for n in (k, *v)} | {"other", "background"}
    return TableEncoder(table=table_for(names))


def _sofa_like_a_seat_cushion(seed=6):
    """A 4x4x2 sofa whose items read as "sofa" and, more, as "seat cushion" (a sub-class
    of cushion), none of them as the sofa's own rare sub-classes; a background wall far
    away keeps the map's mean off the sofa."""
    rng = np.random.default_rng(seed)
    sofa = [(x, y, z) for x in range(4) for y in range(4) for z in range(2)]
    wall = [(20 + x, 0, z) for x in range(12) for z in range(12)]
    lean = np.asarray(vec("sofa")) + 1.5 * np.asarray(vec("seat cushion"))
    obj = lean + 0.05 * rng.standard_normal((len(sofa), 32))
    obj /= np.linalg.norm(obj, axis=1, keepdims=True)
    E = np.concatenate([obj, _rows("background", len(wall), rng, 0.05)]).astype(np.float32)
    return LatentMap(E, kind="voxels", grid_index=np.asarray(sofa + wall), voxel_size=0.1)


def _names_training(query):
    """The query set over TAX_NAMES (every other label a negative group) and its X, y."""
    enc = _names_encoder()
    qs = TaxonomyHeuristic(taxonomy=TAX_NAMES, n_antonyms="all").expand(
        query, ExpansionContext(encoder=enc)
    )
    X, y, _ = training_set(enc, qs)
    return qs, X, y


def _readings_by_hand(m, items, query):
    """The query's margin against its best competitor on ``items``, computed here from
    the definition, under both readings: "top" (a side scores the mean of its 2 best
    names) and "name" (the better of that and its first name: the label)."""
    qs, X, y = _names_training(query)
    c = _centred_cosines(m, items, X)
    pos, neg = c[y == 1], c[y == 0]
    sizes = list(qs.provenance["negative_groups"])
    groups = np.split(neg, np.cumsum(sizes)[:-1])
    top = {
        "top": lambda g: np.sort(g)[-2:].mean(),
        "name": lambda g: max(g[0], np.sort(g)[-2:].mean()),
    }
    return {r: f(pos) - max(f(g) for g in groups) for r, f in top.items()}


def _check_names(m, mask, query, **opts):
    opts = {"support_margin": None, "core_margin": None, **opts}
    return _run(m, mask, query, training=_names_training, **opts)


def test_the_label_name_reading_finds_an_object_its_sub_classes_blur():
    """label_name: a sofa that reads as "sofa" but not as its rare sub-classes ties with
    cushion (via "seat cushion") when each side scores its 2 best names; read by its
    label, the sofa wins clearly. The cushion query on the same sofa stays absent."""
    m = _sofa_like_a_seat_cushion()
    sofa = np.zeros(m.n, bool)
    sofa[:32] = True
    by_hand = _readings_by_hand(m, MapTopology(m).region(np.arange(32), 1), "sofa")
    assert abs(by_hand["top"]) < 0.1 < by_hand["name"]
    margin = (by_hand["top"] + by_hand["name"]) / 2
    keep, info = _check_names(m, sofa, "sofa", margin=margin, label_name=False)
    assert not keep.any() and info["best_margin"] == pytest.approx(by_hand["top"], abs=1e-4)
    keep, info = _check_names(m, sofa, "sofa", margin=margin)
    assert keep[:32].all() and info["best_margin"] == pytest.approx(by_hand["name"], abs=1e-4)
    # the cushion query on the sofa: no reading lets it through
    cushion = _readings_by_hand(m, MapTopology(m).region(np.arange(32), 1), "cushion")
    assert max(cushion.values()) < 0.05
    assert not _check_names(m, sofa, "cushion", margin=0.05)[0].any()


def test_a_near_tie_under_one_reading_does_not_carry_a_component_along():
    """keep_margin: a component that is not strong itself must be kept under both
    readings. The sofa ties with "cushion" under the top reading and loses under the
    label's, so a present cushion query does not keep it."""
    rng = np.random.default_rng(7)
    m = _sofa_like_a_seat_cushion()
    # a real cushion beside the sofa, one cell apart
    cushion_cells = [(6 + x, y, z) for x in range(2) for y in range(2) for z in range(2)]
    E = np.concatenate([np.asarray(m.embeddings), _rows("cushion", 8, rng, 0.05)])
    grid = np.concatenate([np.asarray(m.grid_index), np.asarray(cushion_cells)])
    m2 = LatentMap(E.astype(np.float32), kind="voxels", grid_index=grid, voxel_size=0.1)
    mask = np.zeros(m2.n, bool)
    mask[:32] = True
    mask[-8:] = True
    sofa_only = _readings_by_hand(m2, MapTopology(m2).region(np.arange(32), 1), "cushion")
    keep_margin = sofa_only["top"] - 0.01  # the sofa is "kept" under the top reading
    assert sofa_only["name"] < keep_margin
    kw = dict(margin=0.05, keep_margin=keep_margin, min_component=4)
    keep, info = _check_names(m2, mask, "cushion", **kw)
    assert info["present"] and keep[-8:].all() and not keep[:32].any()
    # the top reading alone keeps the sofa with the cushion
    keep, _ = _check_names(m2, mask, "cushion", label_name=False, **kw)
    assert keep[:32].all() and keep[-8:].all()


def test_growth_adds_a_region_only_when_the_query_wins_it():
    """grow_margin: a kept bed grows region by region through connected candidates; the
    rest of the bed (won by "bed") is added, a sofa beside it (won by "sofa") is not,
    unless grow_margin is off; with grow_steps its items one step from the bed are."""
    rng = np.random.default_rng(8)
    bed = [(x, y, z) for x in range(6) for y in range(3) for z in range(2)]  # 36 items
    more_bed = [(x, y, z) for x in range(6) for y in range(3, 5) for z in range(2)]  # 24
    sofa = [(x, y, z) for x in range(6, 12) for y in range(2) for z in range(2)]  # 24
    wall = [(30 + x, 0, z) for x in range(12) for z in range(12)]  # keeps the mean neutral
    E = np.concatenate(
        [
            _rows("bed", 36, rng, 0.05),
            _rows("bed", 24, rng, 0.05),
            _rows("sofa", 24, rng, 0.05),
            _rows("background", len(wall), rng, 0.05),
        ]
    ).astype(np.float32)
    grid = np.asarray(bed + more_bed + sofa + wall)
    m = LatentMap(E, kind="voxels", grid_index=grid, voxel_size=0.1)
    topo = MapTopology(m)
    # two additions: more_bed touches the bed only, the sofa touches the bed only
    assert len(topo.components(np.r_[np.zeros(36, bool), np.ones(48, bool)])) == 2
    mask = np.zeros(m.n, bool)
    mask[:36] = True
    above = np.r_[np.ones(84, bool), np.zeros(len(wall), bool)]  # refined score above `grow`

    def run(**opts):
        return _run(m, mask, candidates=above, **opts)

    keep, info = run(grow_margin=None)
    assert keep[:84].all() and info["grown_items"] == 84  # unchecked: the sofa comes along
    keep, info = run()
    assert keep[:60].all() and not keep[60:].any() and info["grown_items"] == 60
    keep, _ = run(grow_steps=1)
    near = np.intersect1d(topo.region(np.arange(36), 1), np.arange(60, 84))
    assert 0 < len(near) < 24
    assert np.array_equal(np.flatnonzero(keep), np.r_[np.arange(60), near])
    # grow_steps without grow_margin bounds every addition: one step into each
    keep, _ = run(grow_margin=None, grow_steps=1)
    one_step = np.intersect1d(topo.region(np.arange(36), 1), np.arange(36, 84))
    assert 0 < np.isin(one_step, np.arange(36, 60)).sum() < 24
    assert np.array_equal(np.flatnonzero(keep), np.r_[np.arange(36), one_step])


def test_growth_on_pixel_maps_stays_in_the_frame():
    """Bed patches in two frames each grow into the rest of their own frame's bed; a
    frame without a kept patch gets nothing."""
    rng = np.random.default_rng(9)
    E = np.concatenate([_rows("sofa", 64, rng, 0.05) for _ in range(3)])
    bed = np.zeros((8, 8), bool)
    bed[1:7, 1:7] = True
    for f in range(3):
        E[64 * f : 64 * (f + 1)][bed.reshape(-1)] = _rows("bed", 36, rng, 0.05)
    m = LatentMap(
        E.astype(np.float32),
        kind="pixels",
        frames=[FrameInfo(n, 8, 8, 64 * i) for i, n in enumerate("abc")],
    )
    core = np.zeros((8, 8), bool)
    core[2:5, 2:5] = True
    mask = np.r_[core.reshape(-1), np.zeros(64, bool), core.reshape(-1)]
    keep, info = _run(m, mask, candidates=np.tile(bed.reshape(-1), 3), min_component=4)
    assert info["present"] and info["grown_items"] == 72
    assert np.array_equal(keep, np.r_[bed.reshape(-1), np.zeros(64, bool), bed.reshape(-1)])


def test_grow_margin_auto_parses_and_refine_seeds_auto_resolves_by_label_groups():
    from quash_plugins.engine.refine import RefineOptions, resolve_seeds

    assert PresenceOptions.parse({"grow_margin": "auto"}).grow_margin == "auto"
    with pytest.raises(ConfigError, match="numbers expected"):
        PresenceOptions.parse({"grow_margin": "automatic"})
    assert RefineOptions.parse({"seeds": "auto"}).seeds == "auto"
    qs = _training("bed")[0]  # taxonomy, n_antonyms: all: label groups
    assert resolve_seeds("auto", qs.provenance) == "top"
    assert resolve_seeds("auto", {"heuristic": "vocabulary"}) == "matched"
    assert resolve_seeds("matched", qs.provenance) == "matched"


def _bed_and_a_sofa_block(seed=9):
    """A 27-item bed block, a 27-item sofa block apart from it and a background wall far
    away (so the map's mean is neither)."""
    rng = np.random.default_rng(seed)
    cube = [(x, y, z) for x in range(3) for y in range(3) for z in range(3)]
    sofa = [(x + 10, y, z) for x, y, z in cube]
    wall = [(30 + x, 0, z) for x in range(12) for z in range(12)]
    E = np.concatenate(
        [_rows("bed", 27, rng), _rows("sofa", 27, rng), _rows("background", len(wall), rng)]
    ).astype(np.float32)
    return LatentMap(E, kind="voxels", grid_index=np.asarray(cube + sofa + wall), voxel_size=0.1)


def test_a_loosely_kept_component_must_look_like_the_strong_ones():
    """keep_like: a component kept without being strong (here, with every keep margin
    off, a sofa block for the bed query) stays only when the cosine of its centred mean
    to the strong components' is at least keep_like; the strong bed is never dropped."""
    m = _bed_and_a_sofa_block()
    mask = np.zeros(m.n, bool)
    mask[:54] = True
    loose = dict(keep_margin=-9.0, core_keep_margin=-9.0)
    keep, info = _check(m, mask, **loose)
    assert info["present"] and keep[:54].all()  # the sofa is kept as a loose component
    # the cosine of the centred means, from the definition
    E = np.asarray(m.embeddings, np.float64)
    E /= np.linalg.norm(E, axis=1, keepdims=True)

    def centred(items):
        v = E[items].mean(axis=0) - E.mean(axis=0)
        return v / np.linalg.norm(v)

    like = float(centred(np.arange(27, 54)) @ centred(np.arange(27)))
    assert like < 0.6
    keep, info = _check(m, mask, keep_like=like - 1e-3, **loose)
    assert keep[:54].all() and info["kept"] == 2
    for value in (like + 1e-3, 0.6):
        keep, info = _check(m, mask, keep_like=value, **loose)
        assert keep[:27].all() and not keep[27:].any() and info["kept"] == 1
    # auto: 0.6 with label groups, as demo:quash-labels
    assert not _check(m, mask, keep_like="auto", **loose)[0][27:].any()
    assert PresenceOptions.parse({"keep_like": "auto"}).keep_like == "auto"
    assert PresenceOptions.parse({"keep_like": 0.6}).keep_like == 0.6
    with pytest.raises(ConfigError, match="numbers expected"):
        PresenceOptions.parse({"keep_like": "like"})


def test_dropped_items_keep_the_last_pass_order_above_the_unmatched():
    """The items the presence check drops sit just under the threshold in the last
    pass's order, above every item the pass did not match: a rejected object still
    ranks where its classifier put it (AP, inverse rank)."""
    m = _object_map()
    common = dict(heuristic=TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"), instances=False)
    plain = Quash(_encoder(), **common).query(m, "chair")
    threshold = float(np.median(plain.scores))  # half the map matches the absent chair
    q = Quash(_encoder(), presence={}, threshold=threshold, **common)
    first = Quash(_encoder(), threshold=threshold, **common).query(m, "chair")
    chair = q.query(m, "chair")
    assert first.mask.any() and not chair.mask.any()
    assert (chair.scores <= threshold).all()
    # the order of the last pass is kept over the whole map
    order = np.argsort(-np.asarray(first.scores, np.float64), kind="stable")
    assert np.all(np.diff(np.asarray(chair.scores, np.float64)[order]) <= 0)
    # a kept object still ranks above what was dropped, as before
    bed = q.query(m, "bed")
    assert bed.scores[~bed.mask].max() < bed.scores[bed.mask].min()


@pytest.mark.parametrize("dim", [1, 2, 16, 384])
def test_map_mean_reads_bounded_blocks_with_the_same_bits(dim):
    """map_mean reads READ_ROWS rows at a time (a zarr map stays within memory), and its
    result is bit for bit that of summing each 65,536-row block in one read, as before;
    region_means does not depend on its block at all."""
    from quash_plugins.engine import presence as pr

    rng = np.random.default_rng(dim)
    n = 150_000
    E = rng.normal(size=(n, dim)).astype(np.float32)
    E[rng.random(n) < 0.1] = 0  # unobserved rows
    m = LatentMap(E)
    widest = []

    def rows_of(i):
        widest.append(len(i))
        return E[i]

    # the rule before: one read per 65,536-row block, its float32 sum into a float64 total
    acc, count = np.zeros(dim, np.float64), 0
    for start in range(0, n, 65536):
        rows = pr._unit(E[start : start + 65536])
        live = np.any(rows != 0, axis=1)
        acc += rows[live].sum(axis=0)
        count += int(live.sum())
    expected = (acc / count).astype(np.float32)
    got = map_mean(m, rows_of)
    assert got.tobytes() == expected.tobytes()
    if dim >= 2:
        assert max(widest) == pr.READ_ROWS
    regions = [rng.choice(n, size=k, replace=False) for k in (5, 40_000, 120_000)]
    one = pr.region_means(regions, lambda i: E[i], block=10**6)
    assert pr.region_means(regions, lambda i: E[i]).tobytes() == one.tobytes()
    assert np.allclose(one[1], pr._unit(E[np.sort(regions[1])]).mean(axis=0), atol=1e-6)


# ------------------------------------------------------------------------ the split
def _pairs_by_hand(points, radius):
    """Every pair of ``points`` within ``radius`` (Chebyshev 1 for cells), by brute force."""
    out = set()
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            d = np.abs(np.asarray(points[i]) - np.asarray(points[j]))
            if d.max() <= 1 if radius is None else np.linalg.norm(d) <= radius:
                out.add((i, j))
    return out


@pytest.mark.parametrize("kind", ["voxels", "points", "pixels"])
def test_neighbour_pairs_among_members(kind):
    """MapTopology.pairs: the neighbours among a set of items, as positions in it, each
    pair once, checked against brute force (26-connected cells, points within the
    radius, 8-connected pixels of one frame)."""
    rng = np.random.default_rng(3)
    if kind == "pixels":
        h, w = 6, 7
        frames = [FrameInfo("a", h, w, 0), FrameInfo("b", h, w, h * w)]
        m = LatentMap(np.ones((2 * h * w, 4), np.float32), kind="pixels", frames=frames)
        members = np.sort(rng.choice(np.arange(h * w, 2 * h * w), 25, replace=False))
        where = [divmod(int(i) - h * w, w) for i in members]
        want = _pairs_by_hand([(r, c, 0) for r, c in where], None)
    else:
        cells = np.unique(rng.integers(0, 5, (60, 3)), axis=0)
        common = dict(kind=kind, voxel_size=0.1)
        if kind == "voxels":
            m = LatentMap(np.ones((len(cells), 4), np.float32), grid_index=cells, **common)
        else:
            m = LatentMap(
                np.ones((len(cells), 4), np.float32),
                positions=(cells * 0.1).astype(np.float32),
                **common,
            )
        members = np.sort(rng.choice(len(cells), 30, replace=False))
        radius = None if kind == "voxels" else 1.5  # in cells: 1.5 voxel sizes
        want = _pairs_by_hand(cells[members], radius)
    i, j = MapTopology(m).pairs(members)
    got = set(zip(i.tolist(), j.tolist()))
    assert got == want and len(got) == len(i)
    assert (i < j).all()


def _bed_on_a_sofa(seed=0):
    """A 10x10 'sofa' slab with a 4x4x2 'bed' block standing on it, matched together as
    one component, and a background wall far away."""
    rng = np.random.default_rng(seed)
    slab = [(x, y, 0) for x in range(10) for y in range(10)]
    bed = [(x, y, z) for x in range(3, 7) for y in range(3, 7) for z in (1, 2)]
    wall = [(30 + x, 0, z) for x in range(15) for z in range(15)]
    E = np.concatenate(
        [_rows("sofa", len(slab), rng), _rows("bed", len(bed), rng), _rows("other", len(wall), rng)]
    ).astype(np.float32)
    return LatentMap(E, kind="voxels", grid_index=np.asarray(slab + bed + wall), voxel_size=0.1)


def test_a_component_of_two_objects_is_split_and_its_object_kept():
    """split: a component that holds a bed on a sofa is judged whole and piece by piece.
    Whole, the sofa's items outweigh the bed's and the bed is absent; split on its items'
    label scores, the bed's own items win (core margin by hand), and only they are kept.
    The whole's grown margin is what each piece is judged by in the grown test."""
    m = _bed_on_a_sofa()
    mask = np.zeros(m.n, bool)
    mask[:132] = True  # the slab and the bed: one component
    bed = np.arange(100, 132)
    whole = _margins_by_hand(m, np.arange(132))
    assert min(whole.values()) < 0  # the whole reads as sofa
    keep, info = _check(m, mask, support_margin=0.12, split=None)
    assert not keep.any() and info["present"] is False and "pieces" not in info
    core = min(_margins_by_hand(m, bed).values()) - 0.3 / np.sqrt(len(bed))
    assert core > 0.12  # the bed's own items clear the core margin
    keep, info = _check(m, mask, support_margin=0.12, split=2.5)
    assert info["present"] and info["pieces"] >= 2
    assert keep[bed].mean() > 0.9 and not keep[:100].any()
    # a piece inherits its whole's grown margin: the best grown margin is the whole's
    grown_whole = _check(m, mask, support_margin=0.12, split=None)[1]["best_margin"]
    assert info["best_margin"] == grown_whole
    # the bed matched alone is kept whole, split or not
    only = np.zeros(m.n, bool)
    only[bed] = True
    alone, _ = _check(m, only, support_margin=0.12, split=None)
    assert alone[bed].all()
    split_keep, split_info = _check(m, only, support_margin=0.12, split=2.5)
    assert (split_keep == alone).all()
    assert split_info["pieces"] == 0  # a component strong as a whole is not split


def test_split_is_validated():
    assert PresenceOptions.parse({"split": 2}).split == 2.0
    assert PresenceOptions.parse({}).split == 2.5  # the chosen default
    assert PresenceOptions.parse({"split": None}).split is None
    with pytest.raises(ConfigError, match="split"):
        PresenceOptions.parse({"split": 0})


def test_an_empty_unresolved_query_names_the_label_it_was_nearest_to():
    """A description that resolves to no label (cosine under min_similarity) is judged as
    its own concept; when what beat it in the map is the label its text is nearest to, the
    empty answer says so and how to ask for that label."""
    m = _object_map()
    nap = np.asarray(vec("bed")) * 0.45 + np.asarray(vec("zzz")) * 0.89
    enc = TableEncoder(
        table={**_encoder().table, "a place to nap": (nap / np.linalg.norm(nap)).tolist()}
    )
    h = TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all")
    res = h.resolve_query("a place to nap", ExpansionContext(encoder=enc))
    assert res["how"] == "none" and res["nearest"] == "bed" and res["cosine"] < 0.5
    assert res["min_similarity"] == 0.5
    q = Quash(enc, h, presence={}, threshold=-10.0, instances=False)
    nap_result = q.query_many(m, ["a place to nap"])[0]
    assert not nap_result.mask.any()
    assert nap_result.queryset.provenance["presence"]["rival"] == "bed"
    words = nap_result.presence
    assert f"nearest: 'bed', cosine {res['cosine']} < min_similarity 0.5" in words
    assert "if you meant 'bed', ask for it by name" in words
    # asked for by name, the bed is found
    assert q.query_many(m, ["bed"])[0].mask[:27].all()
    # a rival that is not the nearest label: the resolution is told, not the advice
    prov = {**nap_result.queryset.provenance}
    prov["presence"] = {**prov["presence"], "rival": "sofa"}
    assert "nearest: 'bed'" in presence_words(prov)
    assert "if you meant" not in presence_words(prov)
    # every component too small, or nothing matched: the resolution is told too (it was
    # dropped, so the demo's "where the milk is kept cold" named no label)
    small = {"checked": True, "present": False, "components": 5}
    small.update(largest_component=3, min_component=8)
    for info in (small, {"checked": True, "present": False, "components": 0}):
        words = presence_words({**prov, "presence": info})
        assert words.startswith("absent: ") and "nearest: 'bed'" in words, words
        assert "if you meant" not in words
    # a query that resolved adds nothing
    prov["resolved"] = {**prov["resolved"], "how": "embedding", "to": "bed"}
    assert "nearest:" not in presence_words(prov)
    assert "nearest:" not in presence_words({**prov, "presence": small})


def _refit_lost_the_object(
    fallback=0.03, first_on_bed=True, presence=None, quash=None, first_items=27
):
    """A bed query whose refit matched only the sofa specks (single items: nothing passes)
    while its first pass had matched the bed block (its first ``first_items`` items, a
    connected part of it; or, ``first_on_bed=False``, the specks too), run through the
    presence pass as the pipeline runs it."""
    from quash_plugins.core import registry
    from quash_plugins.engine.answer import Pending, classifier_words, presence_pass

    m = _object_map()
    qs, X, y = _training("bed")
    q = quash or Quash(
        _encoder(),
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"),
        refine={},
        presence={"fallback": fallback, "reseed": False} if presence is None else presence,
        instances=False,
    )
    first_clf = registry.create("classifiers", "nearest-sample", k=2).fit(X, y)
    refit = registry.create("classifiers", "nearest-sample", k=2).fit(X, y)
    specks = np.r_[np.zeros(27, bool), np.ones(m.n - 27, bool)]
    first_hit = np.arange(m.n) < first_items if first_on_bed else specks
    # the rest of the bed scores just under the threshold, as a first pass scores the rest
    # of an object it half found (so the refit's negatives, drawn from the lower half of
    # the scores, are specks)
    rest = ~specks & ~first_hit & first_on_bed
    first_raw = np.where(first_hit, 1.0, np.where(rest, -0.1, -1.0)).astype(np.float32)
    raw = np.where(specks, 1.0, -1.0).astype(np.float32)
    qs.provenance["refine"] = {"applied": True, "first_pass": "first"}
    p = Pending(qs, X, y, refit, {}, raw=raw, mask=raw > 0, display=raw.copy())
    p.first = (first_clf, first_raw)
    presence_pass(q, m, [p], np.ones(m.n, bool))
    return p, classifier_words(p)


def test_a_refit_that_lost_the_object_falls_back_to_the_first_pass():
    """presence.fallback: when no component of the refined mask passes, the first pass's
    mask is checked with every presence margin raised, and answers if an object passes:
    its kept components, its scores, its classifier."""
    p, words = _refit_lost_the_object()
    record = p.queryset.provenance["presence"]
    assert record["present"] is True and record["fallback"]["present"] is True
    assert record["fallback"]["margins_raised_by"] == 0.03
    assert record["kept_items"] == record["largest_kept"] == 27
    assert np.array_equal(p.mask, np.r_[np.ones(27, bool), np.zeros(p.mask.size - 27, bool)])
    assert p.queryset.provenance["refine"]["answered_by"] == "first pass"
    assert "the first pass did" in words and p.first is None
    assert p.raw[p.mask].min() > 0 >= p.raw[~p.mask].max()  # the mask is score > threshold
    # the same check with the raised margins, by hand: the bed block passes it
    opts = PresenceOptions(fallback=0.03)
    raised = PresenceOptions(margin=0.08, core_margin=0.15, support_margin=0.15, grow=None)
    from quash_plugins.engine.presence import fallback_options

    assert fallback_options(opts) == PresenceOptions(**{**vars(raised), "fallback": None})
    _, info = _run(_object_map(), p.mask, **{**vars(raised), "fallback": None})
    assert info["present"] and info["kept_items"] == 27


def test_the_fallback_keeps_absence_and_can_be_turned_off():
    # the first pass matched only specks too: still absent, nothing kept
    p, _ = _refit_lost_the_object(first_on_bed=False)
    record = p.queryset.provenance["presence"]
    assert not p.mask.any() and record["present"] is False
    assert record["fallback"]["present"] is False
    assert "answered_by" not in p.queryset.provenance["refine"]
    # margins raised past what the bed block wins by: the fallback finds nothing either
    p, _ = _refit_lost_the_object(fallback=5.0)
    assert not p.mask.any() and p.queryset.provenance["presence"]["fallback"]["present"] is False
    # fallback: null is the rule before it
    p, words = _refit_lost_the_object(fallback=None)
    assert not p.mask.any() and "fallback" not in p.queryset.provenance["presence"]
    assert "refined as" in words
    with pytest.raises(ConfigError, match="fallback must be >= 0"):
        PresenceOptions.parse({"fallback": -0.1})
    assert PresenceOptions.parse({"fallback": None}).fallback is None


def test_the_first_pass_mask_is_computed_once_for_reseed_and_fallback():
    """A query that ``reseed`` cannot save and ``fallback`` then checks reads the first
    pass's mask twice: it is computed on the first read, kept, and dropped with the
    first pass once the presence check is done."""
    from quash_plugins.engine.answer import Pending, _first_pass

    qs, X, y = _training("bed")
    raw = np.array([1.0, -1.0, 0.5, 2.0], np.float32)
    observed = np.array([True, True, True, False])
    p = Pending(qs, X, y, None, {}, raw=raw, mask=raw > 0, display=raw.copy())
    p.first = ("first", raw)
    clf, first_raw, mask = _first_pass(p, 0.0, observed)
    assert clf == "first" and first_raw is raw
    assert mask.tolist() == [True, False, True, False]  # unobserved items never match
    assert _first_pass(p, 0.0, observed)[2] is mask  # kept, not computed again
    # both second chances on one query: the records of both, and the first pass dropped
    p, _ = _refit_lost_the_object(first_on_bed=False, presence={"reseed": True, "fallback": 0.03})
    record = p.queryset.provenance["presence"]
    assert record["present"] is False and not p.mask.any()
    assert record["reseed"]["first_pass_present"] is False
    assert record["fallback"]["present"] is False and p.first is None


def test_the_fallback_changes_nothing_when_the_refit_passes():
    """A refit whose mask passes answers as without the option (same mask, same scores,
    no fallback record), through the pipeline."""
    m = _object_map()
    common = dict(heuristic=TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"), instances=False)
    off = Quash(_encoder(), refine={}, presence={}, **common).query(m, "bed")
    on = Quash(_encoder(), refine={}, presence={"fallback": 0.03}, **common).query(m, "bed")
    assert off.queryset.provenance["refine"]["applied"] and off.mask[:27].any()
    assert np.array_equal(on.mask, off.mask) and np.array_equal(on.scores, off.scores)
    assert "fallback" not in on.queryset.provenance["presence"]
    assert PresenceOptions().fallback is None  # off unless a config asks for it


def test_reseed_refits_on_what_the_first_pass_check_kept():
    """presence.reseed: when nothing of the refined mask passes, the refit is done again
    with the items the check keeps of the first pass's mask as its only map positives;
    that refit's mask is checked and answers. Its scores are the new classifier's."""
    from quash_plugins.engine.refine import RefineOptions, pseudo_labels

    p, words = _refit_lost_the_object(presence={"reseed": True})
    record = p.queryset.provenance["presence"]
    assert record["present"] is True and "fallback" not in record
    reseed = record["reseed"]
    assert reseed == {
        "first_pass_present": True,
        "first_pass_kept": 27,
        "present": True,
        "positives": 27,
    }
    assert p.queryset.provenance["refine"]["reseeded"] == 27
    assert "refitted on the 27 items the presence check kept of the first pass" in words
    assert presence_words(p.queryset.provenance) == (
        "present (1 of 1 components kept; found by a second refit on the 27 items the "
        "first pass kept)"
    )
    assert np.array_equal(p.mask, np.r_[np.ones(27, bool), np.zeros(p.mask.size - 27, bool)])
    assert p.first is None
    # the new classifier, fitted by hand on the same samples, gives the same scores
    m = _object_map()
    qs, X, y = _training("bed")
    first_raw = np.r_[np.ones(27), -np.ones(m.n - 27)].astype(np.float32)
    Xm, ym = pseudo_labels(
        m, first_raw, first_raw > 0, np.ones(m.n, bool), RefineOptions(), "bed", "matched"
    )
    assert ym.sum() == 27 and len(ym) == m.n  # the block's items, every speck a negative
    from quash_plugins.core import registry

    by_hand = registry.create("classifiers", "svm-rbf").fit(np.r_[X, Xm], np.r_[y, ym])
    expected = by_hand.decision_function(np.asarray(m.embeddings))
    assert np.allclose(p.raw[p.mask], expected[p.mask], atol=1e-5)
    assert (expected[:27] > 0).all() and (expected[27:] <= 0).all()


def test_reseed_can_count_an_object_smaller_than_min_component():
    """reseed_min_component (4 by default): the first pass matched only 6 of the bed's 27
    items (a laptop of 7 voxels found alone), under min_component (8). At 4, reseed's
    checks count an object of 4 items, so those 6 seed the second refit, which finds most
    of the bed. Turned off (null, or min_component itself), 6 items are no object and
    nothing is reseeded."""
    from quash_plugins.engine.presence import reseed_options

    p, _ = _refit_lost_the_object(presence={"reseed_min_component": 4}, first_items=6)
    record = p.queryset.provenance["presence"]
    assert record["present"] is True
    assert record["reseed"] == {
        "first_pass_present": True,
        "first_pass_kept": 6,
        "present": True,
        "positives": 6,
        "first_pass_small_object": True,
    }
    # the second refit finds more of the bed than its 6 seeds, and no speck
    assert p.mask[:6].all() and p.mask[:27].sum() > 20 and not p.mask[27:].any()
    # the default ({}) is the same rule
    default, _ = _refit_lost_the_object(presence={}, first_items=6)
    assert np.array_equal(default.mask, p.mask) and np.array_equal(default.raw, p.raw)
    assert default.queryset.provenance["presence"] == record
    # turned off: 6 items are no object, nothing seeds a second refit
    for presence in ({"reseed_min_component": None}, {"reseed_min_component": 8}):
        p, _ = _refit_lost_the_object(presence=presence, first_items=6)
        record = p.queryset.provenance["presence"]
        assert not p.mask.any() and record["present"] is False
        assert record["reseed"] == {
            "first_pass_present": False,
            "first_pass_kept": 0,
            "present": False,
        }
    # turned off, refine.min_seed (10) kept items still seed it: 9 are an object, too few
    p, _ = _refit_lost_the_object(presence={"reseed_min_component": None}, first_items=9)
    assert not p.mask.any()
    assert p.queryset.provenance["presence"]["reseed"] == {
        "first_pass_present": True,
        "first_pass_kept": 9,
        "present": False,
    }
    p, _ = _refit_lost_the_object(presence={"reseed_min_component": 4}, first_items=9)
    assert p.queryset.provenance["presence"]["reseed"]["positives"] == 9 and p.mask[:9].all()
    # under the smallest object, nothing either: 3 items
    p, _ = _refit_lost_the_object(presence={"reseed_min_component": 4}, first_items=3)
    assert not p.mask.any() and p.queryset.provenance["presence"]["reseed"]["present"] is False
    # the options of reseed's two checks: only min_component changes
    opts = PresenceOptions(reseed_min_component=4)
    assert PresenceOptions().reseed_min_component == 4
    off = PresenceOptions(reseed_min_component=None)
    assert reseed_options(off) == off
    assert reseed_options(opts) == PresenceOptions(
        **{**vars(opts), "min_component": 4, "grown_min_component": 8}
    )
    assert (
        reseed_options(PresenceOptions(min_component=2, reseed_min_component=4)).min_component == 2
    )
    assert PresenceOptions.parse({"reseed_min_component": "5"}).reseed_min_component == 5
    with pytest.raises(ConfigError, match="reseed_min_component must be >= 1 or null"):
        PresenceOptions.parse({"reseed_min_component": 0})


def test_reseed_min_component_never_changes_what_the_check_without_it_finds():
    """The smaller object is only a second check, where the usual one found none: with
    the whole bed in the first pass's mask, the option's answer and record are those of
    the rule without it, and no check counts a 4-item object (hard selection seed 102: one
    check counting both let 13 small pieces seed the floor's refit beside its object,
    and the refit passed nothing)."""
    from unittest import mock

    import quash_plugins.engine.presence as presence
    from quash_plugins.engine.answer import _check_small

    without, _ = _refit_lost_the_object(presence={"reseed_min_component": None})
    with mock.patch.object(presence, "presence_check", wraps=presence.presence_check) as spy:
        p, _ = _refit_lost_the_object(presence={"reseed_min_component": 4})
    assert [c.args[3].min_component for c in spy.call_args_list] == [8, 8, 8]
    assert np.array_equal(p.mask, without.mask) and np.array_equal(p.raw, without.raw)
    assert p.queryset.provenance["presence"] == without.queryset.provenance["presence"]
    assert without.queryset.provenance["presence"]["reseed"]["positives"] == 27
    # _check_small by itself: a found object is returned as it is, without a second check
    calls = []

    def check(mask, options, candidates=None):
        calls.append(options)
        return mask, {"present": options == "small"}

    found = {"present": True}
    assert _check_small(check, "m", "k", found, "small") == ("k", found, False) and not calls
    none = {"present": False}
    assert _check_small(check, "m", "k", none, None) == ("k", none, False) and not calls
    assert _check_small(check, "m", "k", none, "small") == ("m", {"present": True}, True)
    assert calls == ["small"]
    calls.clear()
    assert _check_small(check, "m", "k", none, "other") == ("k", none, False)
    assert calls == ["other"]


def _five_sofa_items_inside_a_bed(seed=0):
    """A 5x5x5 block of bed items with a line of 5 sofa items through its middle, and
    far from it a 6x6x6 block of chair items and one of background (so the map's mean,
    which the check subtracts, is not the bed's)."""
    rng = np.random.default_rng(seed)
    cube = lambda n, at: [(at + x, y, z) for x in range(n) for y in range(n) for z in range(n)]  # noqa: E731
    grid = np.asarray(cube(5, 0) + cube(6, 20) + cube(6, 40))
    bed = np.arange(len(grid)) < 125
    line = bed & (grid[:, 0] == 2) & (grid[:, 1] == 2)
    E = np.concatenate(
        [
            np.where(line[:125, None], _rows("sofa", 125, rng), _rows("bed", 125, rng)),
            _rows("chair", 216, rng),
            _rows("background", 216, rng),
        ]
    )
    m = LatentMap(E.astype(np.float32), kind="voxels", grid_index=grid, voxel_size=0.1)
    return m, line


def test_grown_min_component_counts_a_small_component_by_its_own_items_only():
    """A bed query that matched only the 5 sofa items in the middle of a bed: their grown
    region is mostly bed, so it wins; their own items are sofa. With min_component 4 the
    grown test makes them an object; with grown_min_component 8 they must win by their
    own items (core or support), and do not."""
    m, line = _five_sofa_items_inside_a_bed()
    keep, info = _run(m, line.copy(), min_component=4, grow=None)
    assert info["present"] and info["best_margin"] > 0.05 and keep[line].all()
    assert info["best_core_margin"] < 0.12 and info["best_support_margin"] < 0.12
    keep, info = _run(m, line.copy(), min_component=4, grow=None, grown_min_component=8)
    assert not info["present"] and not keep.any()
    # the bed's own items are an object either way: a 6-item piece of it passes by its core
    bed = np.zeros(m.n, bool)
    bed[np.flatnonzero(~line)[:6]] = True
    for extra in ({}, {"grown_min_component": 8}):
        _, info = _run(m, bed, min_component=4, grow=None, **extra)
        assert info["present"] and info["best_core_margin"] > 0.12
    # reseed_options sets it for reseed's two checks
    from quash_plugins.engine.presence import reseed_options

    assert reseed_options(PresenceOptions(reseed_min_component=4)).grown_min_component == 8
    with pytest.raises(ConfigError, match="grown_min_component must be >= 1 or null"):
        PresenceOptions.parse({"grown_min_component": 0})


def test_reseed_keeps_absence_and_can_be_turned_off():
    # the first pass matched only specks: nothing passes there, no second refit
    p, _ = _refit_lost_the_object(first_on_bed=False, presence={"reseed": True})
    record = p.queryset.provenance["presence"]
    assert not p.mask.any() and record["present"] is False
    assert record["reseed"] == {"first_pass_present": False, "first_pass_kept": 0, "present": False}
    assert "reseeded" not in p.queryset.provenance["refine"]
    # off: the rule before it
    p, words = _refit_lost_the_object(fallback=None)
    assert not p.mask.any() and "reseed" not in p.queryset.provenance["presence"]
    assert PresenceOptions().reseed is True  # on unless a config turns it off
    with pytest.raises(ConfigError, match="reseed must be true or false"):
        PresenceOptions.parse({"reseed": "yes"})


def test_reseed_classifies_every_reseeded_query_in_one_shared_pass():
    """Two queries reseeded in one presence pass: one more pass over the map, not two."""
    from quash_plugins.core import registry
    from quash_plugins.engine.answer import Pending, presence_pass

    m = _object_map()
    q = Quash(
        _encoder(),
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"),
        refine={},
        presence={"reseed": True},
        instances=False,
    )
    passes = []
    classify = q._classify

    def counting(lmap, classifiers, progress, client=None):
        passes.append(len(classifiers))
        return classify(lmap, classifiers, progress, client)

    q._classify = counting
    specks = np.r_[np.zeros(27, bool), np.ones(m.n - 27, bool)]
    pending = []
    for _ in range(2):
        qs, X, y = _training("bed")
        qs.provenance["refine"] = {"applied": True, "first_pass": "first"}
        clf = registry.create("classifiers", "nearest-sample", k=2).fit(X, y)
        raw = np.where(specks, 1.0, -1.0).astype(np.float32)
        p = Pending(qs, X, y, clf, {}, raw=raw, mask=raw > 0, display=raw.copy())
        p.first = (clf, np.where(specks, -1.0, 1.0).astype(np.float32))
        pending.append(p)
    presence_pass(q, m, pending, np.ones(m.n, bool))
    assert passes == [2]
    assert all(p.mask[:27].all() and not p.mask[27:].any() for p in pending)
    assert all(p.timings["presence"] > 0 for p in pending)


def test_reseed_changes_nothing_when_the_refit_passes():
    m = _object_map()
    common = dict(heuristic=TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all"), instances=False)
    off = Quash(_encoder(), refine={}, presence={}, **common).query(m, "bed")
    on = Quash(_encoder(), refine={}, presence={"reseed": True}, **common).query(m, "bed")
    assert off.mask[:27].any()
    assert np.array_equal(on.mask, off.mask) and np.array_equal(on.scores, off.scores)
    assert "reseed" not in on.queryset.provenance["presence"]
