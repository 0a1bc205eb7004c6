"""The map side of a query: first pass, finish, refinement pass, presence check.

:meth:`Quash.query_many <quash_plugins.engine.pipeline.Quash.query_many>` hands each
query here as a :class:`Pending` (its query set, training set and fitted classifier,
from :meth:`Quash._prepare <quash_plugins.engine.pipeline.Quash._prepare>`), and
:func:`answer` fills in its ``(N,)`` vectors, in place, in the order of the data flow:

1. **classify**: one pass over the map for every query (``Quash._classify`` picks the
   executor: in this process, on Dask or on the GPU);
2. :func:`finish`: the classifier's map-level postprocess, the floor of unobserved
   items, the mask and the display scores;
3. :func:`refine_pass` (``refine:``): each query re-fitted on its map samples
   (:mod:`quash_plugins.engine.refine`), all of them classified again in one shared pass;
4. :func:`presence_pass` (``presence:``): the presence check
   (:mod:`quash_plugins.engine.presence`) on each final mask (and, when nothing of the
   refined one passes: with ``reseed``, a second refit seeded by what passes on the
   first pass's mask, classified in one more shared pass; with ``fallback``, the first
   pass's mask itself), and the scores of the items it drops or adds moved across the
   threshold.

The pipeline's ``_answer`` is a thin delegate to :func:`answer`.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from sklearn.base import clone

from ..core.types import LatentMap, QuerySet
from .classify import warn_unobserved

if TYPE_CHECKING:
    from .pipeline import Quash


@dataclass
class Pending:
    """One query on its way through :meth:`Quash.query_many`."""

    queryset: QuerySet
    X: np.ndarray
    y: np.ndarray
    clf: Any
    timings: dict[str, float]
    raw: np.ndarray | None = None
    mask: np.ndarray | None = None
    display: np.ndarray | None = None
    #: the items the presence check dropped (None until it runs)
    rejected: np.ndarray | None = None
    #: the first pass's classifier and scores, kept by refinement for the presence
    #: check's ``reseed`` and ``fallback`` (None without them); the presence check adds
    #: the first pass's mask the first time it needs it (:func:`_first_pass`)
    first: tuple[Any, np.ndarray] | tuple[Any, np.ndarray, np.ndarray] | None = None


def answer(
    quash: Quash,
    lmap: LatentMap,
    pending: list[Pending],
    progress: Any = None,
    client: Any = None,
) -> np.ndarray:
    """The map side of :meth:`Quash.query_many` for ``pending``, in place: the first pass
    (one for all of them), :func:`finish`, the refinement pass and the presence check,
    as the config asks. Returns the ``(N,)`` bool ``observed`` mask.

    Each query then holds ``raw``, ``mask`` and ``display`` ``(N,)`` vectors (9 bytes
    an item; with the presence check's ``fallback``, 4 more from the refinement pass to
    the presence check: the first pass's scores). ``LazyQuery.to_zarr`` calls it for
    one group of queries at a time; ``client`` runs the passes on that Dask client (see
    ``Quash._classify``).
    """
    t = time.perf_counter()
    if progress is not None:
        progress(0)  # the map pass starts: the text side is done
    scores, observed = quash._classify(lmap, [p.clf for p in pending], progress, client)
    warn_unobserved(lmap, observed)
    t_cls = (time.perf_counter() - t) / max(1, len(pending))
    for p, raw in zip(pending, scores):
        p.timings["classify"] = t_cls
        t = time.perf_counter()
        p.raw, p.mask, p.display = finish(p.clf, raw, observed, quash.threshold)
        p.timings["postprocess"] = time.perf_counter() - t
    del scores
    if quash.refine is not None:
        refine_pass(quash, lmap, pending, observed, progress, client)
    if quash.presence is not None:
        presence_pass(quash, lmap, pending, observed, client)
    return observed


def finish(
    clf: Any, raw: Any, observed: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map-level postprocess, unobserved floor, mask and display scores of one query."""
    from ..core.interfaces import Classifier

    raw = np.asarray(raw, dtype=np.float32)
    every = bool(observed.all())  # the common case: no gather, scatter or floor
    if type(clf).postprocess_scores is not Classifier.postprocess_scores:
        if every:
            raw = np.array(clf.postprocess_scores(raw), dtype=np.float32)
        elif observed.any():
            raw[observed] = np.asarray(clf.postprocess_scores(raw[observed]), np.float32)
    if every:
        floor = min(float(raw.min()), threshold) - 1.0 if raw.size else 0.0
    elif observed.any():
        floor = min(float(raw[observed].min()), threshold) - 1.0
    else:
        floor = threshold - 1.0
    if not every:
        raw[~observed] = floor
    mask = raw > threshold
    if not every:
        mask &= observed
    return raw, mask, display_scores(clf, raw, observed, threshold)


def display_scores(clf: Any, raw: np.ndarray, observed: np.ndarray, threshold: float) -> np.ndarray:
    """The classifier's display scores of ``raw``, 0 for unobserved items."""
    display = np.asarray(clf.display_scores(raw, threshold), dtype=np.float32)
    if not observed.all():
        display[~observed] = 0.0
    return display


def refine_pass(
    quash: Quash,
    lmap: LatentMap,
    pending: list[Pending],
    observed: np.ndarray,
    progress: Any,
    client: Any = None,
) -> None:
    """Re-fit each query on its map samples and classify again, in one shared pass."""
    from .refine import resolve_seeds

    presence = quash.presence
    keep_first = presence is not None and (presence.fallback is not None or presence.reseed)
    todo = []
    with _per_query(quash, pending, "refitting") as advance:
        for p in _counted(pending, advance):
            t = time.perf_counter()
            seeds = resolve_seeds(quash.refine.seeds, p.queryset.provenance)
            fitted = _refit(quash, lmap, p, p.raw, p.mask, observed, seeds)
            seed_matches = int(p.mask.sum())
            if fitted is None:
                p.queryset.provenance["refine"] = {
                    "applied": False,
                    "seed_matches": seed_matches,
                    "seeds": seeds,
                }
                p.timings["refine"] = time.perf_counter() - t
                continue
            refined, ym = fitted
            p.queryset.provenance["refine"] = {
                "applied": True,
                "seeds": seeds,
                "seed_matches": seed_matches,
                "map_positives": int(ym.sum()),
                "map_negatives": int(len(ym) - ym.sum()),
            }
            p.timings["refine"] = time.perf_counter() - t
            todo.append((p, refined))
    if not todo:
        if progress is not None:
            progress(lmap.n)  # the second pass is not needed: count it as done
        return
    t = time.perf_counter()
    scores, _ = quash._classify(lmap, [r for _, r in todo], progress, client)
    share = (time.perf_counter() - t) / len(todo)
    for (p, refined), raw in zip(todo, scores):
        p.queryset.provenance["refine"]["first_pass"] = _describe(p.clf)
        if keep_first and p.queryset.provenance.get("negative_groups"):
            p.first = (p.clf, p.raw)  # 4 bytes an item more, until the presence check
        p.clf = refined
        p.raw, p.mask, p.display = finish(refined, raw, observed, quash.threshold)
        p.timings["reclassify"] = share


def presence_pass(
    quash: Quash,
    lmap: LatentMap,
    pending: list[Pending],
    observed: np.ndarray,
    client: Any = None,
) -> None:
    """The presence check (:mod:`quash_plugins.engine.presence`) on each final mask.

    Items it drops or adds get new scores (:func:`_moved_scores`), so the mask stays
    ``score > threshold``. Two second chances for a refined query (with label groups) of
    which nothing passes, in this order:

    - ``reseed``: the first pass's mask is checked with the same margins; if an object
      passes there, the refit is done again with only that object's kept items as its
      map positives (:func:`_reseeded`), every such query classified again in one shared
      pass, and the new mask is checked the same way; it answers if an object passes
      (``provenance["presence"]["reseed"]``). With ``reseed_min_component``, each of the
      two checks that finds no object is done once more, counting an object of that
      many items (:func:`_check_small`);
    - ``fallback``: the first pass's mask is checked with each presence margin raised by
      ``fallback``; if an object passes there, the first pass's kept components and
      scores are the answer (``provenance["presence"]["fallback"]``).
    """
    from .presence import presence_check, reseed_options
    from .refine import take_rows

    def rows_of(index: np.ndarray) -> np.ndarray:
        return take_rows(lmap, index)

    opts = quash.presence
    small_opts = reseed_options(opts) if opts.reseed_min_component is not None else None
    topology, mu = quash._topology.get(lmap, rows_of)
    checked: list[tuple[Pending, Any, np.ndarray, dict[str, Any], float]] = []
    again: list[tuple[int, Any, dict[str, Any]]] = []
    with _per_query(quash, pending, "presence check of") as advance:
        for p in _counted(pending, advance):
            if topology.kind is None:
                p.queryset.provenance["presence"] = {"checked": False, "why": topology.why}
                p.first = None
                continue
            t = time.perf_counter()
            n_strings = len(p.queryset.positives) + len(p.queryset.negatives)
            reps = max(1, len(p.y) // max(1, n_strings))  # prompt templates, mode "all"
            groups = p.queryset.provenance.get("negative_groups")
            if groups and reps > 1:
                groups = [int(g) * reps for g in groups]
            label = p.queryset.provenance.get("label")
            head = p.queryset.positives.index(label) if label in p.queryset.positives else 0

            def check(mask, options, candidates=None, p=p, groups=groups, head=head, reps=reps):
                return presence_check(
                    mask,
                    p.X,
                    p.y,
                    options,
                    topology,
                    mu,
                    rows_of,
                    groups=groups,
                    head=head,
                    reps=reps,
                    candidates=candidates,
                )

            keep, info = check(p.mask, opts, _candidates(quash, p, p.raw, observed))
            if not info["present"] and groups and p.first is not None and opts.reseed:
                clf, record = _reseeded(quash, lmap, p, observed, check, small_opts)
                info["reseed"] = record
                if clf is not None:
                    again.append((len(checked), clf, record))
            checked.append((p, check, keep, info, time.perf_counter() - t))
    if again:
        # the reseeded refits: one shared pass over the map for all of them
        t = time.perf_counter()
        scores, _ = quash._classify(lmap, [clf for _, clf, _ in again], None, client)
        share = (time.perf_counter() - t) / len(again)
        for (i, clf, record), raw in zip(again, scores):
            p, check, keep, info, spent = checked[i]
            raw, mask, display = finish(clf, raw, observed, quash.threshold)
            candidates = _candidates(quash, p, raw, observed)
            r_keep, r_info = check(mask, opts, candidates)
            r_keep, r_info, small = _check_small(
                check, mask, r_keep, r_info, small_opts, candidates
            )
            record["present"] = bool(r_info["present"])
            if small:
                record["small_object"] = True
            if r_info["present"]:
                p.clf, p.raw, p.mask, p.display = clf, raw, mask, display
                p.queryset.provenance["refine"]["reseeded"] = record["positives"]
                keep, info = r_keep, r_info
            info["reseed"] = record
            checked[i] = (p, check, keep, info, spent + share)
    for p, check, keep, info, spent in checked:
        t = time.perf_counter()
        _answer_presence(quash, p, check, keep, info, observed)
        p.timings["presence"] = spent + time.perf_counter() - t


def _per_query(quash: Quash, pending: list[Pending], what: str) -> Any:
    """Progress over ``pending``'s queries, ``"{config}: {what} {n} queries"``; from
    :data:`~quash_plugins.engine.pipeline.PROGRESS_QUERIES` queries, as the text side's
    (a refit and a presence check take about 0.1 s a query: 69 queries, 7 s and 11 s)."""
    from ..core.progress import progress
    from .pipeline import PROGRESS_QUERIES

    n = len(pending)
    return progress(n if n >= PROGRESS_QUERIES else 0, f"{quash.name}: {what} {n} queries")


def _counted(items: list[Pending], advance: Any) -> Iterator[Pending]:
    """``items``, ``advance(1)`` after each one's loop body (a ``continue`` included)."""
    for item in items:
        yield item
        advance(1)


def _candidates(quash: Quash, p: Pending, raw: np.ndarray, observed: np.ndarray) -> Any:
    """The items growth may add (refined scores only), or None."""
    grow = quash.presence.grow
    refined = (p.queryset.provenance.get("refine") or {}).get("applied", False)
    return (raw > grow) & observed if grow is not None and refined else None


def _check_small(
    check: Any,
    mask: np.ndarray,
    keep: np.ndarray,
    info: dict[str, Any],
    small_opts: Any,
    candidates: Any = None,
) -> tuple[np.ndarray, dict[str, Any], bool]:
    """One of ``reseed``'s checks, ``keep`` and ``info``, done once more with
    ``small_opts`` (``reseed_min_component``) when it found no object; and whether that
    second check's answer is the one returned.

    The second check runs only where the first found nothing, so the option can turn an
    empty answer into an object and never changes an object the check without it found. Why
    not one check counting small objects as well: its small pieces then seed the refit
    beside the object (hard selection seed 102: the floor's 19 kept items became 87, from
    13 more components of 4-7 items, and the refit they seeded passed nothing).
    """
    if info["present"] or small_opts is None:
        return keep, info, False
    s_keep, s_info = check(mask, small_opts, candidates)
    if not s_info["present"]:
        return keep, info, False
    return s_keep, s_info, True


def _reseeded(
    quash: Quash,
    lmap: LatentMap,
    p: Pending,
    observed: np.ndarray,
    check: Any,
    small_opts: Any = None,
) -> tuple[Any, dict[str, Any]]:
    """The presence check's ``reseed`` for one query whose refined mask passed nothing:
    the refit done again on the items the check keeps of the first pass's mask (the same
    margins, no growth), and its provenance record; the refit is None when nothing
    passes there, or fewer items are kept than ``refine.min_seed``.

    With ``reseed_min_component`` (``small_opts``, from
    :func:`~quash_plugins.engine.presence.reseed_options`), a check that finds no object,
    or too few items to seed, is done again counting an object of that many items
    (:func:`_check_small`), and such an object seeds the refit however few its items.

    Why: the refit takes the ``n_positives`` best-scored items as its positives, and for
    a small object (a laptop of 4-21 items) they are mostly its desk; the first pass's
    own presence check had told the laptop from the desk.
    """
    _, first_raw, first_mask = _first_pass(p, quash.threshold, observed)
    min_seed = quash.refine.min_seed
    f_keep, f_info = check(first_mask, quash.presence)
    small = False
    if small_opts is not None and (not f_info["present"] or (f_keep & observed).sum() < min_seed):
        # no object, or too few items to seed: count an object of reseed_min_component
        # items, and let such an object seed the refit however few its items
        s_keep, s_info = check(first_mask, small_opts)
        if s_info["present"]:
            f_keep, f_info, small = s_keep, s_info, True
            min_seed = min(min_seed, small_opts.min_component)
    f_keep &= observed
    record: dict[str, Any] = {
        "first_pass_present": bool(f_info["present"]),
        "first_pass_kept": int(f_keep.sum()),
        "present": False,
    }
    if small:
        record["first_pass_small_object"] = True
    if not f_info["present"] or f_keep.sum() < min_seed:
        return None, record
    opts = replace(quash.refine, min_seed=min_seed)
    fitted = _refit(quash, lmap, p, first_raw, f_keep, observed, "matched", opts)
    if fitted is None:
        return None, record
    clf, ym = fitted
    record["positives"] = int(ym.sum())
    return clf, record


def _first_pass(
    p: Pending, threshold: float, observed: np.ndarray
) -> tuple[Any, np.ndarray, np.ndarray]:
    """The first pass's classifier, scores and mask, kept for ``reseed`` and ``fallback``.

    The mask is computed once, on the first call, and kept in ``p.first`` until the
    presence check drops it: a query that ``reseed`` could not save and ``fallback``
    then checks reads it twice.
    """
    if len(p.first) == 2:
        clf, raw = p.first
        p.first = (clf, raw, (raw > threshold) & observed)
    return p.first


def _refit(
    quash: Quash,
    lmap: LatentMap,
    p: Pending,
    scores: np.ndarray,
    mask: np.ndarray,
    observed: np.ndarray,
    seeds: str,
    opts: Any = None,
) -> tuple[Any, np.ndarray] | None:
    """The refinement classifier fitted on ``p``'s text rows and the map samples that
    ``scores`` and ``mask`` give (:func:`~quash_plugins.engine.refine.pseudo_labels`),
    and the samples' labels; None when there are too few to fit. Both the refinement
    pass and ``reseed`` fit here; ``opts`` (default ``quash.refine``) are the refine
    options of the fit.
    """
    from .refine import pseudo_labels

    # the map negatives are a seeded draw: seeded by the concept (the label a query
    # resolves to), so "wood stove", "a fireplace" and "fireplace" draw the same ones
    # and a sub-class query answers as its label does
    salt = p.queryset.provenance.get("label") or p.queryset.query
    opts = quash.refine if opts is None else opts
    extra = pseudo_labels(lmap, scores, mask, observed, opts, str(salt), seeds)
    if extra is None:
        return None
    Xm, ym = extra
    clf = clone(quash._refine_template).fit(np.concatenate([p.X, Xm]), np.concatenate([p.y, ym]))
    return clf, ym


def _answer_presence(
    quash: Quash, p: Pending, check: Any, keep: np.ndarray, info: dict[str, Any], observed
) -> None:
    """The fallback, the moved scores and the provenance record of one checked query."""
    from .presence import fallback_options

    opts, threshold = quash.presence, quash.threshold
    groups = p.queryset.provenance.get("negative_groups")
    first_answers = False
    if not info["present"] and groups and p.first is not None and opts.fallback is not None:
        # the refit can lose a small object that the first pass had (a laptop whose
        # 100 best-scored items are mostly its desk): the first pass's mask is checked
        # with every presence margin raised, and answers if an object passes there
        first_clf, first_raw, first_mask = _first_pass(p, threshold, observed)
        f_keep, f_info = check(first_mask, fallback_options(opts))
        info["fallback"] = {
            k: f_info.get(k) for k in ("present", "kept", "kept_items", "best_margin")
        }
        info["fallback"]["margins_raised_by"] = float(opts.fallback)
        if f_info["present"]:
            first_answers = True
            p.clf, p.raw, p.mask, keep = first_clf, first_raw, first_mask, f_keep
            p.queryset.provenance["refine"]["answered_by"] = "first pass"
            info.update(
                present=True,
                **{k: f_info[k] for k in ("kept", "kept_items", "largest_kept")},
            )
    p.first = None
    keep &= observed
    p.rejected = p.mask & ~keep
    if first_answers or (p.mask & ~keep).any() or (keep & ~p.mask).any():
        p.raw = _moved_scores(p.raw, p.mask, keep, observed, threshold)
        p.mask = keep
        p.display = display_scores(p.clf, p.raw, observed, threshold)
    rival = info.pop("rival_negative", None)
    if rival is not None and 0 <= rival < len(p.queryset.negatives):
        info["rival"] = p.queryset.negatives[rival]
    p.queryset.provenance["presence"] = info


def _moved_scores(
    raw: np.ndarray, mask: np.ndarray, keep: np.ndarray, observed: np.ndarray, threshold: float
) -> np.ndarray:
    """A copy of ``raw`` with the presence check's changes to ``mask`` (now ``keep``).

    Dropped items sit just below the threshold, below every kept item and above the
    items the last pass did not match, in the last pass's order: a rejected object still
    ranks where its classifier put it among what is left. Items added by growth sit just
    above the threshold, below every match of the last pass.
    """
    dropped = mask & ~keep
    added = keep & ~mask
    raw = raw.copy()
    if dropped.any():
        # the last pass's order in a band under the threshold; every unmatched item
        # moves down by twice the band (their order kept), so none outranks a dropped one
        lo, hi = float(raw[dropped].min()), float(raw[dropped].max())
        band = 1e-3
        raw[observed & ~mask & ~keep] -= 2 * band
        value = threshold - band * (0.95 - 0.9 * (raw[dropped] - lo) / max(hi - lo, 1e-12))
        ceil = np.nextafter(np.float32(threshold), np.float32(-np.inf))
        raw[dropped] = np.minimum(value, ceil)
    if added.any():
        # just above the threshold, below every match of the last pass
        lo, hi = float(raw[added].min()), float(raw[added].max())
        kept = keep & mask
        top = float(raw[kept].min()) if kept.any() else threshold + 1e-3
        room = min(1e-3, top - threshold)
        value = threshold + room * (0.05 + 0.9 * (raw[added] - lo) / max(hi - lo, 1e-12))
        floor = np.nextafter(np.float32(threshold), np.float32(np.inf))
        raw[added] = np.maximum(value, floor)
    return raw


def _describe(clf: Any) -> str:
    """A classifier in a few words: its ``describe()``, else its class name."""
    describe = getattr(clf, "describe", None)
    return describe() if callable(describe) else type(clf).__name__


def classifier_words(p: Pending) -> str:
    """The classifier that gave ``p`` its scores, with the first pass's when refinement
    re-fitted it: ``"NearestSampleClassifier(k=2), refined as RbfSvmClassifier(...) on
    the map's items"`` (``QueryResult.classifier``)."""
    refine = p.queryset.provenance.get("refine") or {}
    first = refine.get("first_pass")
    words = _describe(p.clf)
    if refine.get("answered_by") == "first pass":
        # the presence check's fallback: the refit found no object, the first pass did
        return f"{words} (its refit on the map's items found no object; the first pass did)"
    reseeded = refine.get("reseeded")
    if first and reseeded:
        return (
            f"{first}, refined as {words} on the map's items (refitted on the {reseeded} "
            "items the presence check kept of the first pass)"
        )
    return f"{first}, refined as {words} on the map's items" if first else words
