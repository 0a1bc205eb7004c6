"""What an evaluation scores on a map: its labels (one per name), the valid items, each
query's label, and the presence and absence queries (:func:`plan_queries`), and why a
map without ground truth cannot be scored (:func:`missing_ground_truth`). Public through
:mod:`quash_plugins.evaluation.report`.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap
from .metrics import valid_items
from .queries import (
    label_key,
    match_labels,
    one_per_spelling,
    parse_queries,
    say_twice,
    spelling,
    warn_scored_absent,
)

# records log as they did before the split, from the module that evaluates
log = logging.getLogger("quash_plugins.evaluation.report")

#: Negative or aggregate labels the paper removes from the query set.
DEFAULT_EXCLUDE = (
    "void",
    "unlabeled",
    "unlabelled",
    "misc",
    "objects",
    "seating",
    "furniture",
    "appliances",
    "other",
)


def missing_ground_truth(lmap: LatentMap) -> str:
    """Why ``lmap`` cannot be evaluated: which of its labels and label names is missing,
    and where each comes from for the map's format."""
    where = lmap.source.get("path", "the map")
    adapter = lmap.source.get("adapter", "")
    if lmap.labels is not None:
        if adapter.startswith(("vlmaps", "openscene")):
            fix = (
                "Give them to the adapter: in the config, 'adapter: {name: "
                f"{adapter}, label_names: names.txt}}' (one name a line, in label order), "
                "or -o label_names=names.txt on the command line."
            )
            if adapter.startswith("vlmaps"):
                fix += " VLMaps forks write them as obj2cls_dict.txt beside the map."
        else:
            fix = "Write the map with its label names (the NPZ array label_names (L,))."
        return (
            f"{where} has per-item labels but no label names, which evaluation needs to "
            f"match queries to labels. {fix}"
        )
    hint = (
        " Upstream VLMaps writes no ground truth; its forks store grid_semantic (3-D) or "
        "grid_<n>_gt.npy (top-down) with obj2cls_dict.txt."
        if adapter.startswith("vlmaps")
        else ""
    )
    own = (
        " To score your own map, convert it (quash convert MAP map.npz) and add the arrays "
        "labels (N,) int (-1: unlabelled) and label_names (L,) "
        "(docs/evaluation.md#ground-truth-for-your-own-map)."
    )
    return (
        f"{where} has no ground-truth labels (per-item labels and their names); evaluation "
        f"needs them. Use a labelled map, e.g. `quash make-scene`.{hint}{own}"
    )


def first_label_of(names: Sequence[str]) -> dict[str, int]:
    """Each label name's first index: the label a query of that name is scored against
    (the others of the same name are merged into it by :func:`plan_queries`)."""
    first: dict[str, int] = {}
    for i, n in enumerate(names):
        first.setdefault(n, i)
    return first


def _one_label_per_name(labels: np.ndarray, names: list[str], where: Any) -> np.ndarray:
    """``labels`` with every label whose name an earlier label has (``label_names``
    ``['bed', 'sofa', 'bed']``) counted as that earlier one, in a new array (the map's
    own is never written): a query of "bed" has the items of both as its ground truth.
    Counted by the name, the items of the other "bed" were false positives."""
    first = first_label_of(names)
    same = {i: first[n] for i, n in enumerate(names) if first[n] != i}
    if not same:
        return labels
    merged = labels.copy()
    for i, j in same.items():
        merged[labels == i] = j
    twice = sorted({names[j] for j in same.values()})
    log.warning(
        "%s: 'label_names' gives %s to more than one label (%s): each name is scored as "
        "one label, the items of all of them its ground truth",
        where,
        ", ".join(repr(n) for n in twice),
        "; ".join(f"{names[j]!r}: {j}, {i}" for i, j in same.items()),
    )
    return merged


def plan_queries(
    lmap: LatentMap,
    queries: Any = None,
    exclude: Sequence[str] = DEFAULT_EXCLUDE,
    absent: Sequence[str] = (),
    query_file: str | Path | None = None,
    absent_in_file: Collection[str] | None = None,
) -> tuple[np.ndarray, np.ndarray, dict[str, str], list[str], list[str]]:
    """What :func:`evaluate` scores on ``lmap``: its labels, the valid items, each query's
    label, the presence queries and the absence queries. Raises :class:`QuashError` for a
    map without ground truth or a query list it cannot score (before any config runs).

    ``query_file`` is the file ``queries`` came from and ``absent_in_file`` the absence
    queries that came from it (None: all of ``absent``, when there is a file); an error
    names the file and its section."""
    for arg, value in (("queries", queries), ("absent", absent), ("exclude", exclude)):
        if isinstance(value, str):  # iterated, 'piano' was five one-letter queries
            raise QuashError(
                f"{arg} is the text {value!r}, not a list: give a list of texts "
                f"({arg}=[{value!r}]; split a comma-separated list: {value!r}.split(','))."
            )
    if lmap.labels is None or not lmap.label_names:
        raise QuashError(missing_ground_truth(lmap))
    names = list(lmap.label_names)
    labels = _one_label_per_name(np.asarray(lmap.labels), names, lmap.source.get("path", "the map"))
    valid = valid_items(labels, names, exclude)
    if not valid.any():
        where = lmap.source.get("path", "the map")
        if labels.size == 0:
            raise QuashError(
                f"{where}: the map has no items, so there is nothing to score. Give a map "
                "with items and their 'labels' (quash make-scene writes one); check that "
                "the map was written after its items were added."
            )
        unlabelled = not (labels >= 0).any()
        why = (
            "every item's label is negative (unlabelled)"
            if unlabelled
            else f"every labelled item has an excluded label ({', '.join(exclude)})"
        )
        raise QuashError(
            f"{where}: no item can be scored: {why}. With no ground truth, a query that "
            "matches nothing would count as a right absence. Give a map whose 'labels' "
            "name its items (quash make-scene writes one)"
            + ("." if unlabelled else ", or exclude fewer labels (quash eval --exclude).")
        )
    counts = (
        np.bincount(labels[valid], minlength=len(names))
        if valid.any()
        else np.zeros(len(names), int)
    )
    given_queries = queries is not None
    excluded = {label_key(e) for e in exclude}  # as valid_items drops them
    if queries is None:
        queries = [n for i, n in enumerate(names) if counts[i] > 0 and label_key(n) not in excluded]
    gt_of = match_labels(parse_queries(queries), names, absent=absent, source=query_file)
    for q, g in gt_of.items():
        if label_key(g) in excluded:
            raise QuashError(
                f"{f'{query_file}: query' if query_file else 'Query'} {q!r}: its label "
                f"{g!r} is excluded (--exclude: neither TP nor FP, "
                "never queried); remove it from the queries or from --exclude."
            )
    index = first_label_of(names)
    unknown_here = [q for q, g in gt_of.items() if g not in index or counts[index[g]] == 0]
    presence = [q for q in gt_of if q not in unknown_here]
    in_file = set(absent if absent_in_file is None else absent_in_file) if query_file else set()
    counts_of = {n: int(counts[i]) for i, n in enumerate(names)}
    _check_absent(absent, presence, counts_of, query_file=query_file, in_file=in_file)
    absence, twice = one_per_spelling([*unknown_here, *absent])
    say_twice("absence queries", twice, _twice_from(twice, query_file, in_file, unknown_here))
    # a present query scored as absent is warned about (match_labels warned about those
    # whose label is no label of the map) unless it, or its label, is listed absent: those
    # are said at INFO
    listed = {label_key(a) for a in absent}
    texts = {spelling(a) for a in absent}
    quiet = {q for q in unknown_here if label_key(gt_of[q]) in listed or spelling(q) in texts}
    for q in unknown_here:
        if gt_of[q] in index and q not in quiet:
            warn_scored_absent(
                q, gt_of[q], "is a label that no item of the map carries", query_file
            )
    no_items = [q for q in unknown_here if gt_of[q] in index and q in quiet]
    if no_items:
        log.info(
            "queries of labels no item of the map carries, scored as absence queries: %s",
            ", ".join(no_items),
        )
    no_label = [q for q in unknown_here if gt_of[q] not in index and q in quiet]
    if no_label:
        log.info(
            "queries whose label is not a label of the map, scored as absence queries: %s",
            ", ".join(no_label),
        )
    if not presence and not absence:
        if given_queries:  # an empty query list or file, not the map's labels
            where = f"{query_file} holds" if query_file else "the query list holds"
            raise QuashError(
                f"No query to evaluate: {where} no present and no absent query. List "
                "labels or {text: label} items under 'present' and texts under 'absent', "
                "or leave the queries out to score every label of the map."
            )
        raise QuashError("No query to evaluate: the map has no label left after --exclude.")
    return labels, valid, gt_of, presence, absence


def _twice_from(
    twice: dict[str, list[str]],
    query_file: str | Path | None,
    in_file: Collection[str],
    from_queries: Collection[str],
) -> str | None:
    """Where the absence queries given twice came from, for the warning: the query file
    (its 'present' queries that are absence queries, and its 'absent' list), and
    ``--absent`` beside it; None without a query file (the queries and ``--absent``)."""
    if not query_file:
        return None
    texts = [t for k, v in twice.items() for t in (k, *v)]
    where = []
    if any(t in in_file or t in from_queries for t in texts):
        where.append(str(query_file))
    if any(t not in in_file and t not in from_queries for t in texts):
        where.append("--absent")
    return " and ".join(where) or None


def _check_absent(
    absent: Sequence[str],
    presence: Sequence[str],
    counts: dict[str, int],
    query_file: str | Path | None = None,
    in_file: Collection[str] = (),
):
    """Refuse an absence query that is a present query, or a label the map's items carry:
    its score would count a method that finds the object as wrong. An absence query in
    ``in_file`` came from ``query_file``'s ``absent`` (the present queries, when there is
    a file, from the file too): the message names the file and the section. A present
    and an absence query are the same query whatever their case and spacing
    (:func:`~quash_plugins.evaluation.queries.spelling`): both spellings are named."""
    have = {label_key(n): n for n, c in counts.items() if c}
    present_as = {spelling(p): p for p in presence}
    there = f"in {query_file}" if query_file else "the queries"
    for a in absent:
        here = f"under 'absent' in {query_file}" if a in in_file else "--absent"
        if a in presence:
            raise QuashError(
                f"{a!r} is both a present query ({there}) and an absence query ({here}): "
                "remove it from one of them."
            )
        p = present_as.get(spelling(a))
        twin = (
            f"{p!r} is a present query ({there}) and {a!r}, the same query in another case "
            f"or spacing, an absence query ({here})"
            if p is not None
            else None
        )
        name = have.get(label_key(a))
        if name is not None:
            what = f"{query_file}: absence query {a!r} (under 'absent')"
            what = what if a in in_file else f"Absence query {a!r} (--absent)"
            raise QuashError(
                f"{what}: {counts[name]} items of the map carry the label "
                f"{name!r}, so it is not absent{f'; {twin}' if twin else ''}. Absence "
                "queries name objects the map does not have; remove it from "
                f"{here.removeprefix('under ')}."
            )
        if twin:
            raise QuashError(f"{twin}: remove it from one of them.")
