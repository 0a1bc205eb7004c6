"""The presence check: a query whose object is not in the map comes back empty.

After the last pass (the refined one when ``refine`` is on), the matched items are split
into connected components (:class:`MapTopology`: 26-connected voxels, points within a
linking radius, 8-connected pixels of one frame). Each component's **mean embedding** is
classified against the query set itself, both sides centred (the map's mean row is
subtracted from the region mean, the query set's mean text row from the text rows): the
query's positives (mean of the ``k`` best cosines) against each competitor, each other
label with its sub-classes when the heuristic records ``negative_groups`` (the
``taxonomy`` heuristic with ``n_antonyms: all``, ``label-list``), else each negative
alone. Each side is read two ways (``label_name``): as the mean of its ``k`` best
names, and as the better of that and its label name alone (the query's label, or the
query itself when it names no label; each competitor group's first name, its label).
A component's *margin* is how far the query wins; two regions are judged:

- the **grown region**: the component and its neighbours ``dilate`` steps away;
- the **core**: the component's own items, whose margin must also beat
  ``size_margin / sqrt(size)`` (the mean of a few selected items is noisy and leans
  towards the query);
- the **core against the support** (``support_margin``): the core's margin against the
  one competitor that wins the grown region, less the same ``size_margin / sqrt(size)``.

The query is **present** when some component of at least ``min_component`` items has a
grown-region margin above ``margin``, a core margin above ``core_margin`` or a margin
against its support above ``support_margin``. Then (``mode: filter``) every such
component whose grown-region margin is above ``keep_margin``, core margin above
``core_keep_margin`` or margin against its support above ``support_margin`` is kept;
``mode: gate`` keeps the whole mask. A test passed under either reading counts; a
component kept without being strong must be kept under both readings and, with
``keep_like``, its centred mean must have a cosine of at least ``keep_like`` to that of
the strong components (``auto``: 0.6 with label groups, off without). When the query is
not present: an empty mask, ``provenance["presence"]["present"]`` False.

With ``split`` (and label groups), a component that is not strong as a whole is also cut
into pieces, where its items' label-group scores change
(:func:`~quash_plugins.engine.segments.split_components`: Ward's clustering of neighbours), and each piece is judged as a component too: by its whole's
grown-region margin, its own core, and against what wins its own grown region. Why:
a small object and its support, or a rug and the floor it lies on, often match as one
component whose mean is mostly the other object; the whole's test keeps a piece from
passing the grown test that its whole failed (a look-alike's purer piece would). With ``grow``
(refined scores only), the kept components then grow through connected items whose
refined score is above ``grow`` (hysteresis: recovers an object's items just under the
threshold, never a new object); with ``grow_margin``, each addition (the new items of one
connected region) is added only when the query wins its own mean by that margin under
either reading, else (with ``grow_steps``) only its items within that many steps;
``grow_margin: auto`` checks growth (0.0) for a query set with label groups and grows
unchecked without them (a vocabulary standing in for the list), as the default config does.
With ``reseed`` (on by default; label groups and refinement), a query of which nothing
in the refined mask passes is given a second refit: the first pass's mask is checked with
the same margins, and if an object passes there, refinement is done again with only the
items kept there as its map positives; the new refined mask is then checked the same
way, and answers if an object passes. With ``reseed_min_component`` (4 by default,
null turns it off: :func:`reseed_options`), each of those two checks that finds no
object is done once more, counting an object of that many items by its own items only
(``grown_min_component``): a laptop of 7 voxels found alone by the first pass is under
``min_component``, and so is the refit seeded by it
(:func:`~quash_plugins.engine.answer.presence_pass`). Why: the refit's positives, the
100 best-scored items, can be mostly the desk a laptop stands on, while the first pass's
check tells the laptop from the desk.
With ``fallback`` (opt-in; label groups and refinement), a query of which nothing in
the refined mask passes is checked once more on the first pass's mask, under
:func:`fallback_options` (each presence margin raised by ``fallback``, no growth), and
the first pass answers if an object passes there
(:func:`~quash_plugins.engine.answer.presence_pass`): the refit's positives, the 100
best-scored items, can be mostly the desk a laptop stands on. It is off in the shipped
configs: at 0.03 it let an absent refrigerator through on a reported seed of the second
class table (docs/benchmarks.md).

Why a grown region: a matched set is *selected* for looking like the query, so its own
mean leans towards the query (on the proxy scenes every absent label passed such a test).
A speck that matched by noise is judged mostly by its unselected neighbours, a whole
object by itself. Why the core as well: a small object on a support (a book on a shelf,
a cushion on a sofa) is swamped by its support once grown. Why the support as well: such
an object's own items often sit near a third label (a laptop near "desk" and "book"), so
its core loses the contest against every label; what its surroundings say it is not (the
support that wins the grown region) it beats clearly, while a look-alike's speck on
another object loses to that object on its core too (``support_margin: null`` turns
this off, the rule before it). Why the label name: a label's rarer sub-classes
("settee", "chesterfield") sit far from what the encoder sees, so the mean of a group's
best names can let a neighbouring label's sub-class ("seat cushion") tie with an object
that its own label name wins clearly; the second reading keeps the top-k mean for the
groups whose label is the weaker name. Why a kept-only component needs both readings: a
near tie under one reading (cushion on the sofa's voxels) must not carry a look-alike
into a present query's mask. Why ``grow_margin``: unchecked growth runs from a book into
the shelf it stands on. Why centring: a modality offset adds the same vector to
every map row, i.e. a per-string bias to every cosine; subtracting the map's mean
removes it. Why one decision per query: an object that is
there usually has one clear component, while an absent label's best look-alike wins
narrowly; the defaults were chosen so (docs/benchmarks.md).

A map with neither a voxel grid, nor positions, nor frames has no neighbourhood: the
check is skipped (``provenance["presence"] = {"checked": False, "why": ...}``).

This module decides; :mod:`~quash_plugins.engine.readings` measures (the centred text
rows, the margins of each reading, the judgement of a set of components).

Examples
--------
>>> PresenceOptions.parse({"min_component": 4}).min_component
4
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, fields, replace
from typing import Any

import numpy as np

from ..core.errors import ConfigError, check_options
from ..core.types import LatentMap
from .readings import READ_ROWS, Readings, _unit, map_mean, region_means
from .segments import split_components
from .topology import MAX_DILATE, MapTopology

__all__ = [
    "KEEP_LIKE",
    "MODES",
    "READ_ROWS",
    "SPLIT_MAX",
    "PresenceOptions",
    "TopologyCache",
    "fallback_options",
    "map_mean",
    "presence_check",
    "region_means",
    "reseed_options",
]

MODES = ("filter", "gate")
#: ``keep_like: auto`` with label groups: demo:quash-labels' value (chosen on seeds 100-102)
KEEP_LIKE = 0.6
#: Largest component that ``split`` clusters (Ward's clustering grows faster than the
#: item count: a larger component is judged whole, as without ``split``)
SPLIT_MAX = 20000


@dataclass
class PresenceOptions:
    """Options of the ``presence`` config section (see the module docstring)."""

    dilate: int = 1
    min_component: int = 8
    margin: float = 0.05
    keep_margin: float = -0.02
    core_margin: float | None = 0.12
    core_keep_margin: float = 0.03
    size_margin: float = 0.3
    flat_margin: float | None = None
    support_margin: float | None = 0.12
    label_name: bool = True
    k: int = 2
    mode: str = "filter"
    grow: float | None = -0.25
    grow_steps: int | None = None
    grow_margin: float | str | None = 0.0
    keep_like: float | str | None = None
    split: float | None = 2.5
    fallback: float | None = None
    reseed: bool = True
    reseed_min_component: int | None = 4
    grown_min_component: int | None = None

    @classmethod
    def parse(cls, options: dict[str, Any]) -> PresenceOptions:
        check_options("presence", options, [f.name for f in fields(cls)])
        try:
            opts = cls(**options)
            opts.dilate, opts.min_component, opts.k = (
                int(opts.dilate),
                int(opts.min_component),
                int(opts.k),
            )
            for key in ("reseed_min_component", "grown_min_component"):
                if getattr(opts, key) is not None:
                    setattr(opts, key, int(getattr(opts, key)))
            for key in ("margin", "keep_margin", "core_keep_margin", "size_margin"):
                setattr(opts, key, float(getattr(opts, key)))
            for key in (
                "core_margin",
                "flat_margin",
                "support_margin",
                "grow",
                "grow_margin",
                "keep_like",
                "split",
                "fallback",
            ):
                if key in ("grow_margin", "keep_like") and getattr(opts, key) == "auto":
                    continue
                if getattr(opts, key) is not None:
                    setattr(opts, key, float(getattr(opts, key)))
            if opts.grow_steps is not None:
                opts.grow_steps = int(opts.grow_steps)
        except (TypeError, ValueError) as exc:
            raise ConfigError(
                f"presence: {exc}; numbers expected (null turns off core_margin, flat_margin, "
                "support_margin, grow, grow_margin, keep_like, split and fallback; grow_margin "
                "and keep_like also take auto)."
            ) from None
        if not 0 <= opts.dilate <= MAX_DILATE or opts.min_component < 1 or opts.k < 1:
            raise ConfigError(
                f"presence: dilate must be in [0, {MAX_DILATE}] (got {opts.dilate}), "
                f"min_component >= 1 "
                f"(got {opts.min_component}) and k >= 1 (got {opts.k})."
            )
        for key in ("reseed_min_component", "grown_min_component"):
            if getattr(opts, key) is not None and getattr(opts, key) < 1:
                raise ConfigError(
                    f"presence: {key} must be >= 1 or null; got {getattr(opts, key)}."
                )
        if opts.grow_steps is not None and opts.grow_steps < 0:
            raise ConfigError(f"presence: grow_steps must be >= 0 or null; got {opts.grow_steps}.")
        for key in ("label_name", "reseed"):
            if not isinstance(getattr(opts, key), bool):
                raise ConfigError(
                    f"presence: {key} must be true or false; got {getattr(opts, key)!r}."
                )
        if opts.split is not None and not opts.split > 0:
            raise ConfigError(f"presence: split must be > 0 or null; got {opts.split}.")
        if opts.fallback is not None and not opts.fallback >= 0:
            raise ConfigError(f"presence: fallback must be >= 0 or null; got {opts.fallback}.")
        if opts.size_margin < 0:
            raise ConfigError(f"presence: size_margin must be >= 0; got {opts.size_margin}.")
        if opts.mode not in MODES:
            raise ConfigError(f"presence: mode must be one of {MODES}; got {opts.mode!r}.")
        return opts


# ---------------------------------------------------------------------- the check
def presence_check(
    mask: np.ndarray,
    X: np.ndarray,
    y: np.ndarray,
    opts: PresenceOptions,
    topology: MapTopology,
    mu: np.ndarray,
    rows_of: Any,
    groups: list[int] | None = None,
    head: int = 0,
    reps: int = 1,
    candidates: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, Any]]:
    """The kept items of ``mask`` and a provenance record.

    ``X, y``: the query set's text rows (positives first, then negatives, as
    :func:`~quash_plugins.engine.training.training_set` builds them). ``groups``: sizes of
    consecutive negative groups (``provenance["negative_groups"]``); the negatives after
    them (the generic ones) form one more group. ``rows_of(index)`` returns the map's rows.
    ``head``: which positive string is the query's label (0, the query itself, when it
    names no label); ``reps``: rows per string (prompt templates, mode ``all``). Both
    serve the ``label_name`` reading.
    """
    comps = topology.components(mask)
    keep = np.zeros(len(mask), bool)
    info: dict[str, Any] = {"checked": True, "components": len(comps), "kept": 0}
    if not comps:
        info.update(present=False, kept_items=0)
        return keep, info
    R = Readings(X, y, opts, topology, mu, rows_of, groups, head, reps)
    scored = R.scored
    J = R.judge(comps)
    if opts.split is not None and groups:
        # a component that is not strong as a whole may hold more than one object (a rug
        # on the floor): its pieces are judged as well
        weak = [i for i in range(len(comps)) if not J["strong"][:, i].any()]
        pieces, of = split_components(
            [comps[i] for i in weak],
            topology,
            R.item_scores,
            opts.split,
            min_size=opts.min_component,
            max_size=SPLIT_MAX,
        )
        info["pieces"] = len(pieces)
        if pieces:
            whole = np.asarray([weak[i] for i in of], np.int64)
            more = R.judge(pieces, [a[whole] for a in J["grown_r"]])
            comps = [*comps, *pieces]
            for key, val in more.items():
                J[key] = (
                    [np.concatenate([a, b]) for a, b in zip(J[key], val)]
                    if isinstance(val, list)
                    else np.concatenate([J[key], val], axis=-1)
                )
    sizes = np.array([len(m) for m in comps])
    grown_r, grown, strong, ok = J["grown_r"], J["grown"], J["strong"], J["ok"]
    big = sizes >= opts.min_component
    if opts.flat_margin is not None:
        big &= J["flat"] > opts.flat_margin
    core_best = support_best = None
    if "core" in J:
        core_best = round(float(J["core"].max(axis=0)[big].max()), 4) if big.any() else None
    if "support" in J:
        support_best = round(float(J["support"].max(axis=0)[big].max()), 4) if big.any() else None
    # a component is strong when it is under either reading, and kept when it is kept
    # under a reading where it is strong, or under both: a near tie under one reading
    # cannot carry a look-alike along
    ok = (strong & ok).any(axis=0) | ok.all(axis=0)
    strong = strong.any(axis=0)
    keep_like = opts.keep_like
    if keep_like == "auto":
        # with label groups the chosen method's value; without them (a vocabulary standing
        # in for the list) off, as demo:quash-vocabulary was measured
        keep_like = KEEP_LIKE if groups else None
    if keep_like is not None:
        # a component kept without being strong must look like the strong ones: the
        # cosine of its centred mean to theirs at least keep_like (a whole shelf that ties
        # with "book" is kept for the book query only if it looks like the books that
        # won clearly)
        loose = ok & ~strong & big
        sk = [comps[i] for i in np.flatnonzero(strong & big)]
        if loose.any() and sk:
            idx = np.flatnonzero(loose)
            proto = _unit(region_means([np.concatenate(sk)], rows_of) - mu)[0]
            like = _unit(region_means([comps[i] for i in idx], rows_of) - mu) @ proto
            ok[idx[like < keep_like]] = False
    grown = grown.max(axis=0)
    present = bool(np.any(strong & big))
    kept = (ok & big) if present else np.zeros(len(comps), bool)
    for members, good in zip(comps, kept):
        if good:
            keep[members] = True
    info.update(
        present=present,
        kept=int(kept.sum()),
        best_margin=round(float(grown[big].max()), 4) if big.any() else None,
        best_core_margin=core_best,
        **({"best_support_margin": support_best} if opts.support_margin is not None else {}),
        largest_kept=int(sizes[kept].max()) if kept.any() else 0,
        largest_component=int(sizes.max()),
        min_component=int(opts.min_component),
    )
    if big.any() and scored:
        # the competitor that the best large component loses most to (or wins least
        # against), as the index of its first negative string: what the query was judged
        # against, for the viewer and the words of an absent decision
        best = int(np.flatnonzero(big)[np.argmax(grown[big])])
        first_row = scored[int(grown_r[0][best].argmin())][0]
        info["rival_negative"] = int(first_row // max(1, reps))
    if opts.mode == "gate":
        keep = mask.copy() if present else np.zeros_like(mask)
    info["kept_items"] = int(keep.sum())
    if candidates is not None and keep.any():
        if opts.grow_margin == "auto":
            # checked growth with a label list; without one (a vocabulary standing in)
            # every connected candidate grows, as it measured better (docs/benchmarks.md)
            opts = replace(opts, grow_margin=0.0 if groups else None)
        keep = _grow(keep, candidates, topology, opts, R.margins)
        info["grown_items"] = int(keep.sum())
    return keep, info


def reseed_options(opts: PresenceOptions) -> PresenceOptions:
    """The options of ``reseed``'s second, smaller-object check
    (``reseed_min_component``, 4 by default): an object of that many items counts
    (``min_component`` if that is smaller), but one under ``min_component`` only by its
    own items, core or support (``grown_min_component``); every margin as it is. With
    the option null, ``opts`` themselves. ``reseed`` runs this check only where its check
    with ``opts`` found no object (:func:`quash_plugins.engine.answer._check_small`).

    Why one might: a laptop of 4-12 voxels that the first pass finds almost alone (7 of
    its 17 items and nothing else) is under ``min_component``, and the refit seeded
    from those items matches those items again. Why not by its grown region: there, a
    6-item component of white cabinets let an absent refrigerator through on a
    selection seed. Why only where nothing was found: counted in the same check, small
    pieces seeded a floor's refit beside the floor, and lost it. Chosen on selection
    seeds, then measured on the reported ones: no absence lower on any row, low-noise
    closed F1 0.915 -> 0.925 (docs/benchmarks.md).

    Examples
    --------
    >>> reseed_options(PresenceOptions()).min_component
    4
    >>> reseed_options(PresenceOptions(reseed_min_component=None)).min_component
    8
    """
    if opts.reseed_min_component is None:
        return opts
    return replace(
        opts,
        min_component=min(opts.min_component, opts.reseed_min_component),
        grown_min_component=opts.min_component,
    )


def fallback_options(opts: PresenceOptions) -> PresenceOptions:
    """The options of the check on the first pass's mask (``fallback``): every presence
    margin (``margin``, ``core_margin``, ``support_margin``) raised by ``fallback``, the
    keep margins as they are, and no growth (``grow`` is a threshold on refined scores)."""
    d = float(opts.fallback or 0.0)
    return replace(
        opts,
        margin=opts.margin + d,
        core_margin=None if opts.core_margin is None else opts.core_margin + d,
        support_margin=None if opts.support_margin is None else opts.support_margin + d,
        grow=None,
        fallback=None,
    )


def _grow(keep, candidates, topology, opts, margins) -> np.ndarray:
    """Hysteresis: the kept components grow through connected ``candidates``. With
    ``grow_margin``, an addition (the new items of one connected candidate region) whose
    own mean the query does not win by that margin under some reading (it is mostly a
    neighbouring object) grows at most ``grow_steps`` steps (none without it)."""
    if opts.grow_margin is None:
        return topology.grow(keep, candidates, opts.grow_steps)
    if opts.grow_margin == "auto":
        raise ValueError("resolve grow_margin: auto for the query set first")
    # the connected regions of new candidates that touch a kept component
    new = topology.components(candidates & ~keep)
    if topology.kind == "pixels":  # a region is grown within one frame
        adds = [m for m in new if keep[topology.region(m, 1)].any()]
    else:
        touching = np.zeros_like(keep)
        touching[topology.region(np.flatnonzero(keep), 1)] = True
        adds = [m for m in new if touching[m].any()]
    if not adds:
        return keep
    won = np.max(np.stack([a.min(axis=1) for a in margins(0, adds)[0]]), axis=0)
    out, near = keep.copy(), np.zeros_like(keep)
    for add, m in zip(adds, won):
        (out if m > opts.grow_margin else near)[add] = True
    if opts.grow_steps:
        out |= topology.grow(keep, near, opts.grow_steps)
    return out


class TopologyCache:
    """One :class:`MapTopology` and map mean per live map (weakly referenced)."""

    def __init__(self) -> None:
        self._state: tuple[Any, MapTopology, np.ndarray | None] | None = None

    def get(self, lmap: LatentMap, rows_of: Any) -> tuple[MapTopology, np.ndarray | None]:
        s = self._state
        if s is not None and s[0]() is lmap:
            return s[1], s[2]
        topo = MapTopology(lmap)
        mu = map_mean(lmap, rows_of) if topo.kind is not None else None
        self._state = (weakref.ref(lmap), topo, mu)
        return topo, mu
