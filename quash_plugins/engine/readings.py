"""What a region of the map says about a query set: the margins the presence check reads.

The presence check (:mod:`quash_plugins.engine.presence`) decides; this module measures.
:class:`Readings` holds a query set's centred text rows, split into the query's
positives and its competitors (each other label with its sub-classes, from
``provenance["negative_groups"]``, else each negative alone), and gives, for any regions
of the map, how far the query wins against each competitor under each reading (the
mean of the ``k`` best names per side, and with ``label_name`` the better of that and the
label's own name), and the judgement of a set of components: their grown region, their
own items (core) and their own items against the competitor that wins the grown region
(support). :func:`map_mean` and :func:`region_means` read the map's rows in bounded
blocks. The module docstring of :mod:`~quash_plugins.engine.presence` says why each test.

Examples
--------
>>> import numpy as np
>>> region_means([np.array([0, 1]), np.array([2])], lambda i: np.eye(3)[i])
array([[0.5, 0.5, 0. ],
       [0. , 0. , 1. ]], dtype=float32)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.expansions import top_mean
from ..core.types import LatentMap
from .topology import MapTopology

#: Rows a summation reads at once (map_mean, region_means): 8192 x D float64 is 24 MiB at
#: D = 384, 64 MiB at D = 1024, whatever the map's size or ``chunk_mb``.
READ_ROWS = 8192


def _unit(a: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return a / np.where(n > 0, n, 1.0)


def map_mean(lmap: LatentMap, rows_of: Any, block: int = 65536) -> np.ndarray:
    """The mean of the map's unit rows (zero rows, i.e. unobserved items, left out).

    Summed in float32 over ``block`` rows at a time, each block into a float64 total; a
    block is read :data:`READ_ROWS` rows at a time and its float32 sum carried on in row
    order, so the result is bit for bit what one read of the block gives, with a bounded
    read."""
    acc = np.zeros(lmap.dim, np.float64)
    count = 0
    # a one-column block sums pairwise, not row by row: read it whole (it is small)
    step = READ_ROWS if lmap.dim >= 2 else block
    for start in range(0, lmap.n, block):
        stop = min(lmap.n, start + block)
        part_sum: np.ndarray | None = None
        for a in range(start, stop, step):
            rows = _unit(rows_of(np.arange(a, min(stop, a + step))))
            live = np.any(rows != 0, axis=1)
            rows = rows[live]
            count += len(rows)
            if part_sum is None:
                part_sum = rows.sum(axis=0)
            elif len(rows):
                # carried in row order: (part_sum + r0) + r1 + ..., as one block's sum is
                part_sum = np.add.reduce(np.concatenate([part_sum[None], rows]), axis=0)
        if part_sum is not None:
            acc += part_sum
    return (acc / max(count, 1)).astype(np.float32)


def region_means(regions: list[np.ndarray], rows_of: Any, block: int = READ_ROWS) -> np.ndarray:
    """The mean unit row of each region, reading at most ``block`` rows at a time (the
    sums are float64 and run in item order whatever ``block`` is: the result does not
    depend on it)."""
    if not regions:
        return np.zeros((0, 0), np.float32)
    owner = np.repeat(np.arange(len(regions)), [len(r) for r in regions])
    items = np.concatenate(regions)
    order = np.argsort(items, kind="stable")
    items, owner = items[order], owner[order]
    sums: np.ndarray | None = None
    for start in range(0, len(items), block):
        part, who = items[start : start + block], owner[start : start + block]
        uniq, inv = np.unique(part, return_inverse=True)
        rows = _unit(np.asarray(rows_of(uniq), np.float64))[inv]
        if sums is None:
            sums = np.zeros((len(regions), rows.shape[1]), np.float64)
        np.add.at(sums, who, rows)
    sizes = np.array([max(len(r), 1) for r in regions], np.float64)
    return (sums / sizes[:, None]).astype(np.float32)


def group_sizes(groups: list[int] | None, n_neg: int) -> list[int]:
    """Consecutive group sizes covering all ``n_neg`` negative rows; without usable groups
    every negative is its own group."""
    if groups:
        groups = [int(g) for g in groups]
        if all(g > 0 for g in groups) and sum(groups) <= n_neg:
            rest = n_neg - sum(groups)
            return [*groups, rest] if rest else groups
    return [1] * n_neg


class Readings:
    """A query set's text rows, centred, and the margins that map regions win by.

    ``X, y``: the query set's text rows (positives first, then negatives, as
    :func:`~quash_plugins.engine.training.training_set` builds them); ``opts``: the
    presence options (:class:`~quash_plugins.engine.presence.PresenceOptions`: ``k``,
    ``label_name``, ``dilate``, the core and support margins, ``size_margin``);
    ``topology`` and ``mu`` (the map's mean row) the map's; ``rows_of(index)`` its rows.
    ``groups``, ``head`` and ``reps`` as :func:`~quash_plugins.engine.presence.presence_check`
    takes them.
    """

    def __init__(
        self,
        X: np.ndarray,
        y: np.ndarray,
        opts: Any,
        topology: MapTopology,
        mu: np.ndarray,
        rows_of: Any,
        groups: list[int] | None = None,
        head: int = 0,
        reps: int = 1,
    ) -> None:
        self.opts, self.topology, self.mu, self.rows_of = opts, topology, mu, rows_of
        self.groups, self.reps = groups, reps
        live = np.any(X != 0, axis=1)
        centre = X[live].mean(axis=0)
        self.P = _unit(X[(y == 1) & live] - centre)
        pos_rows = np.flatnonzero(y == 1)[head * reps : (head + 1) * reps]
        pos_rows = pos_rows[live[pos_rows]]
        self.P_head = _unit(X[pos_rows] - centre) if len(pos_rows) else self.P[:1]
        neg_rows = np.flatnonzero(y == 0)
        self.N = _unit(X[neg_rows] - centre)
        self.nlive = live[neg_rows]
        #: the negative groups scored, as (first row, size): those with a live row
        self.scored: list[tuple[int, int]] = []
        start = 0
        for size in group_sizes(groups, len(self.N)):
            if self.nlive[start : start + size].any():
                self.scored.append((start, size))
            start += size
        # the readings of a group's score: the mean of its k best names, and (label_name)
        # the better of that and its first name alone (the label, or the query itself)
        self.by_name = bool(opts.label_name and groups)

    def item_scores(self, members: np.ndarray) -> np.ndarray:
        """``(n, 1 + groups)``: the query's and each scored group's score of single items
        (the features that ``split`` reads)."""
        opts, N, nlive = self.opts, self.N, self.nlive
        rows = _unit(_unit(np.asarray(self.rows_of(members), np.float32)) - self.mu)
        CN = rows @ N.T
        cols = [top_mean(rows @ self.P.T, opts.k)]
        for start, size in self.scored:
            live_g = nlive[start : start + size]
            cols.append(top_mean(CN[:, start : start + size][:, live_g], opts.k))
        return np.column_stack(cols)

    def margins(self, dilate: int, parts: list[np.ndarray]) -> tuple[list[np.ndarray], np.ndarray]:
        """Per reading, the ``(parts, groups)`` margins of each part's region (grown by
        ``dilate`` steps) against each group; and the flat margin (against the single
        best negative string)."""
        opts, N, nlive, reps = self.opts, self.N, self.nlive, self.reps
        regions = [self.topology.region(m, dilate) for m in parts]
        means = _unit(region_means(regions, self.rows_of) - self.mu)
        sp = top_mean(means @ self.P.T, opts.k)
        CN = means @ N.T
        top, name = [], []
        for start, size in self.scored:
            live_g = nlive[start : start + size]
            block = CN[:, start : start + size]
            top.append(top_mean(block[:, live_g], opts.k if self.groups else 1))
            first = live_g[: min(reps, size)]
            name.append(block[:, : len(first)].mean(axis=1) if first.all() else top[-1])
        if not top:
            top = name = [np.full(len(means), -np.inf)]
        flat = sp - CN[:, nlive].max(axis=1) if nlive.any() else np.full(len(means), np.inf)
        against = [sp[:, None] - np.column_stack(top)]
        if self.by_name:
            sp_name = np.maximum(sp, (means @ self.P_head.T).mean(axis=1))
            against.append(
                sp_name[:, None] - np.maximum(np.column_stack(top), np.column_stack(name))
            )
        return against, flat

    def judge(self, parts: list[np.ndarray], whole_grown: list[np.ndarray] | None = None) -> dict:
        """Per reading, ``(readings, parts)`` strong and kept flags with the margins behind
        them. A piece of a split component (``whole_grown``: its whole's grown margins) is
        judged by its whole's surroundings, by its own items (core) and against what wins
        its own surroundings (support). With ``grown_min_component``, a part under that
        many items is strong by its own items only (core or support)."""
        opts = self.opts
        own_r, flat = self.margins(opts.dilate, parts)
        grown_r = own_r if whole_grown is None else whole_grown
        grown = np.stack([a.min(axis=1) for a in grown_r])  # (readings, parts)
        out = {"grown_r": grown_r, "flat": flat, "grown": grown}
        by_grown, out["ok"] = grown > opts.margin, grown > opts.keep_margin
        own = np.zeros_like(by_grown)  # strong by the part's own items
        if opts.core_margin is not None or opts.support_margin is not None:
            core_r = self.margins(0, parts)[0] if opts.dilate else own_r
            penalty = opts.size_margin / np.sqrt([len(m) for m in parts])
        if opts.core_margin is not None:
            out["core"] = np.stack([a.min(axis=1) for a in core_r]) - penalty
            own |= out["core"] > opts.core_margin
            out["ok"] |= out["core"] > opts.core_keep_margin
        if opts.support_margin is not None:
            # the core against the group that wins the grown region: a small object's support
            rows = np.arange(len(parts))
            out["support"] = (
                np.stack([c[rows, g.argmin(axis=1)] for c, g in zip(core_r, own_r)]) - penalty
            )
            own |= out["support"] > opts.support_margin
            out["ok"] |= out["support"] > opts.support_margin
        if opts.grown_min_component is not None:
            # a part under grown_min_component items is strong by its own items only: its
            # grown region is mostly its neighbours (a look-alike's few items of white
            # cabinets win theirs)
            small = np.asarray([len(m) for m in parts]) < opts.grown_min_component
            by_grown = by_grown & ~small[None, :]
        out["strong"] = by_grown | own
        return out
