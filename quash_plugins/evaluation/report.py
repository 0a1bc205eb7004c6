"""``evaluate``: score method configs on a labelled map; JSON and Markdown reports.

Examples
--------
>>> import numpy as np
>>> from quash_plugins import LatentMap
>>> from quash_plugins.evaluation import evaluate
>>> m = LatentMap(np.eye(3, dtype=np.float32), labels=np.array([0, 1, 2]),
...               label_names=["chair", "sofa", "other"])
>>> table = {"chair": [1, 0, 0], "sofa": [0, 1, 0], "other": [0, 0, 1],
...          "background": [0, .5, .5], "nothing": [.5, 0, .5]}
>>> cfg = {"name": "vlmaps", "encoder": {"name": "table", "table": table},
...        "classifier": "contrast", "cache": False, "instances": False}
>>> r = evaluate(m, [cfg], queries=["chair", "sofa"])
>>> r.configs[0]["mean"]["f1"]
1.0
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap
from .metrics import METRICS, RANKING, absence_score, macro_mean, query_metrics, valid_items
from .queries import (
    label_key,
    load_query_file,
    match_labels,
    one_per_spelling,
    parse_queries,
    say_twice,
    spelling,
    warn_scored_absent,
)

log = logging.getLogger(__name__)

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


@dataclass
class EvalReport:
    """Scores of several configs on one map. ``configs`` is the JSON payload's list;
    ``provenance`` says what was scored (:func:`eval_provenance`)."""

    configs: list[dict[str, Any]]
    queries: list[str]
    absent: list[str]
    results: dict[str, list[Any]] = field(default_factory=dict, repr=False)
    provenance: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        """One line: what was scored on which map, and each config's mean F1 and absence
        (the per-query scores are the fields; ``to_markdown()`` tables them)."""
        where = (self.provenance.get("map") or {}).get("path") if self.provenance else None
        rows = []
        for c in self.configs:
            f1 = (c.get("mean") or {}).get("f1")
            absence = (c.get("absence") or {}).get("score")
            cells = [f"F1 {f1:.3f}" if isinstance(f1, (int, float)) else "F1 -"]
            if self.absent:
                cells.append(
                    f"absence {absence:.2f}" if isinstance(absence, (int, float)) else "absence -"
                )
            rows.append(f"{c.get('name', '?')} {' '.join(cells)}")
        on = f" on {where}" if where else ""
        absent = f" + {len(self.absent)} absent" if self.absent else ""
        n, q = len(self.configs), len(self.queries)
        return (
            f"EvalReport({n} config{'s' * (n != 1)} x {q} quer{'ies' if q != 1 else 'y'}"
            f"{absent}{on}: {'; '.join(rows)})"
        )

    def to_json(self) -> dict[str, Any]:
        """``{"configs": [...], "provenance": {...}}`` (``provenance`` when known)."""
        out: dict[str, Any] = {"configs": self.configs}
        if self.provenance:
            out["provenance"] = self.provenance
        return out

    def to_markdown(self, per_query: bool = True) -> str:
        return report_markdown(self.configs, per_query=per_query)

    def best(self, metric: str = "f1") -> dict[str, Any]:
        """The config with the highest mean ``metric`` (a config with nothing scored, whose
        means are None, ranks last)."""
        return max(
            self.configs, key=lambda c: (c["mean"][metric] is not None, c["mean"][metric] or 0)
        )


def _as_quash(config: Any, overrides: dict[str, Any]):
    from ..engine.pipeline import Quash

    if isinstance(config, Quash):
        return config
    return Quash.from_config(config, **overrides)


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


def _first_label_of(names: Sequence[str]) -> dict[str, int]:
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
    first = _first_label_of(names)
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
    index = _first_label_of(names)
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


def evaluate(
    source: Any,
    configs: Sequence[Any],
    queries: Sequence[str] | None = None,
    exclude: Sequence[str] = DEFAULT_EXCLUDE,
    absent: Sequence[str] = (),
    empty_tolerance: int = 0,
    overrides: dict[str, Any] | None = None,
    on_query: Callable[[str, int], None] | None = None,
    keep_results: bool = False,
    query_file: str | Path | None = None,
    absent_in_file: Collection[str] | None = None,
) -> EvalReport:
    """Score each config once over all queries (one :meth:`Quash.query_many` pass each).

    Parameters
    ----------
    source
        A map path or a :class:`LatentMap` with ``labels`` and ``label_names``.
    configs
        Config paths, dicts, :class:`QuashConfig` or ready :class:`Quash` objects.
    queries
        What to score: label names, ``"text=label"`` items or a ``{text: label}``
        mapping (open-vocabulary queries: the text is the query, the label its ground
        truth; see :func:`parse_queries`). None scores every label present in the map
        (minus ``exclude``). A query of a label of the map that no item carries becomes
        an absence query; a label that is no name of the map is refused (unless it is
        among ``absent``: see :func:`~quash_plugins.evaluation.queries.match_labels`).
    exclude
        Label names whose items are ignored (neither TP nor FP) and never queried.
    absent
        Extra absence queries (labels or free text not in the map).
    empty_tolerance
        An absence query counts as empty when at most this many items match.
    overrides
        Keyword overrides for :meth:`Quash.from_config` (``cache``, ``backend``...).
    keep_results
        Keep each config's :class:`QueryResult` list in ``report.results``.
    on_query
        Called as ``on_query(config_name, n_queries)`` after each config's pass. Within
        a pass, :func:`~quash_plugins.core.progress.progress` counts the map passes in
        items (``"NAME: Q queries, 2 passes over N items"``; quiet with its ``QUIET``).
    query_file
        The query file ``queries`` and ``absent`` came from, recorded in
        ``report.provenance`` (:func:`eval_provenance`) and named in errors; not read here.
    absent_in_file
        The absence queries that came from ``query_file`` (None: all of ``absent``), so
        that an error names the file or ``--absent``, wherever the query came from.
    """
    from ..core.config import QuashConfig
    from ..core.progress import progress
    from ..engine.pipeline import Quash

    overrides = dict(overrides or {})
    if isinstance(configs, (str, Path, Mapping, QuashConfig, Quash)):
        # iterated, "demo:quash-labels" was read as the config files 'd', 'e', 'm'...
        one = repr(str(configs)) if isinstance(configs, (str, Path)) else "config"
        raise QuashError(
            f"configs is one {type(configs).__name__}, not a list: give a list of configs "
            f"(configs=[{one}])."
        )
    if not configs:
        raise QuashError("evaluate needs at least one config.")
    quashes = [_as_quash(c, overrides) for c in configs]
    lmap = source if isinstance(source, LatentMap) else quashes[0].read_map(source)
    labels, valid, gt_of, presence, absence = plan_queries(
        lmap, queries, exclude, absent, query_file=query_file, absent_in_file=absent_in_file
    )
    index = _first_label_of(lmap.label_names)
    from ..engine.topology import MapTopology
    from .ranking import average_precision, inverse_rank, label_segments

    segments = label_segments(labels, MapTopology(lmap)) if presence else None
    used: dict[str, int] = {}
    out, all_results, names = [], {}, []
    for quash, config in zip(quashes, configs):
        name = quash.name
        if name in used:
            used[name] += 1
            stem = Path(str(config)).stem if isinstance(config, (str, Path)) else str(used[name])
            name = f"{name} ({stem})"
        used.setdefault(name, 0)
        names.append(name)
        texts = [*presence, *absence]
        # the map passes are most of a config's time (69 queries of demo:quash-labels on
        # 51,000 voxels: 40 s of 63 s), one shared pass for every query: counted in items
        passes = "1 pass" if quash.passes == 1 else f"{quash.passes} passes"
        counted = "1 query" if len(texts) == 1 else f"{len(texts)} queries"
        what = f"{name}: {counted}, {passes} over {lmap.n} items"
        with progress(lmap.n * quash.passes, what) as advance:
            results = quash.query_many(lmap, texts, progress=advance)
        per_query = {}
        for q, r in zip(presence, results[: len(presence)]):
            truth = labels == index[gt_of[q]]
            per_query[q] = {"label": gt_of[q], **query_metrics(r.mask, truth, valid)}
            # ranking metrics: the order the scores put the items in
            per_query[q]["ap"] = average_precision(r.scores, truth, valid)
            per_query[q]["inv_rank"] = (
                inverse_rank(r.scores, segments, truth, valid) if segments is not None else None
            )
        masks = {q: r.mask for q, r in zip(texts, results)}
        ab = absence_score({q: masks[q] for q in absence}, valid, empty_tolerance)
        for q in absence:  # an absence query of the queries: its label ('bunk bed=bed')
            if q in gt_of:
                ab["per_query"][q] = {"label": gt_of[q], **ab["per_query"][q]}
        # empty as an absence query's mask is: at most empty_tolerance counted items
        ab["present_empty"] = sum(1 for m in per_query.values() if m["n_pred"] <= empty_tolerance)
        out.append(
            {
                "name": name,
                "given": given(quash, results[0].queryset.provenance if results else None),
                "mean": macro_mean(per_query),
                "per_query": per_query,
                "absence": ab,
            }
        )
        if keep_results:
            all_results[name] = results
        if on_query is not None:
            on_query(name, len(texts))
    prov = eval_provenance(
        lmap,
        list(zip(names, quashes)),
        {q: gt_of[q] for q in presence},
        absence,
        query_file=query_file,
        exclude=exclude,
        empty_tolerance=empty_tolerance,
        absent_labels={q: gt_of[q] for q in absence if q in gt_of},
    )
    return EvalReport(out, presence, absence, all_results, prov)


def eval_provenance(
    lmap: LatentMap,
    configs: Sequence[tuple[str, Any]],
    queries: dict[str, str],
    absent: Sequence[str],
    query_file: str | Path | None = None,
    exclude: Sequence[str] = DEFAULT_EXCLUDE,
    empty_tolerance: int = 0,
    absent_labels: dict[str, str] | None = None,
) -> dict[str, Any]:
    """What an evaluation scored, as JSON-ready data (the ``provenance`` of its JSON).

    ``quash_plugins``: the package version; ``map``: the map's source (its ``path`` and
    ``adapter``, and what the file records of the encoder that built it); ``query_file``
    (None without one); ``queries``: ``{text: label}`` of the presence queries;
    ``absent``: the absence queries (the texts queried); ``absent_labels``: ``{text:
    label}`` of those that came from the queries (``bunk bed=bed`` whose label no item
    carries); ``configs``: per table row its ``name``, the
    config ``file`` it was read from (None for the default config, a dict or an object),
    the ``shipped`` name of a shipped config (else None), its ``encoder`` and
    ``templates``: where its prompt templates came from (None without templates; "our
    default list (vlmaps-or-default: no VLMaps installed)");
    ``exclude`` and ``empty_tolerance``.
    """
    from .. import __version__

    return {
        "quash_plugins": __version__,
        "map": {
            k: v for k, v in dict(lmap.source).items() if isinstance(v, (str, int, float, bool))
        },
        "query_file": str(query_file) if query_file else None,
        "queries": dict(queries),
        "absent": list(absent),
        "absent_labels": dict(absent_labels or {}),
        "configs": [_config_provenance(name, quash) for name, quash in configs],
        "exclude": list(exclude),
        "empty_tolerance": empty_tolerance,
    }


def _config_provenance(name: str, quash: Any) -> dict[str, Any]:
    """A row's config: its file (and shipped name, when the package ships it), its
    encoder and where its prompt templates came from."""
    from ..core.shipped import config_dir, shipped_configs

    file = getattr(quash, "config_source", None)
    shipped = None
    if file:
        path = Path(file).resolve()
        if path.parent == config_dir().resolve():
            shipped = next((c.name for c in shipped_configs() if c.path.resolve() == path), None)
    encoder = getattr(quash, "encoder", None)
    return {
        "name": name,
        "file": str(file) if file else None,
        "shipped": shipped,
        "encoder": getattr(encoder, "name", None) if encoder is not None else None,
        "templates": getattr(quash, "templates_source", None),
    }


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


#: What each heuristic gives a method besides the query (the "given" column of a table).
GIVEN = {
    "none": "the query alone",
    "static": "the query + fixed lists",
    "templates": "the query alone",
    "vocabulary": "the query + the shipped vocabulary",
    "adjectives": "the query + the shipped adjectives",
    "lexicon": "the query + the shipped lexicon",
    "llm": "the query + an LLM",
}


def given(quash: Any, provenance: dict[str, Any] | None = None) -> str:
    """What a configured method is given besides the map: the label list or the query alone.

    A heuristic may say it itself with an ``information()`` method; the built-ins are
    described here, and a query set's ``provenance["labels_from"]`` (where the label list
    came from) refines it. Fixed negatives beyond the generic three count as given too.
    """
    from ..core.types import DEFAULT_NEGATIVES

    text = _given_by(quash.heuristic)
    how = (provenance or {}).get("auto")  # the auto heuristic says which it used
    if how == "vocabulary":
        text = GIVEN["vocabulary"]
    elif how == "label list":
        text = "the label list"
    source = (provenance or {}).get("labels_from")
    if source and text.startswith("the label list"):
        parts = [Path(p.strip()).name if "/" in p else p.strip() for p in str(source).split("+")]
        text = f"the label list ({' + '.join(parts)})"
    extra = [n for n in getattr(quash, "negatives", ()) if n not in DEFAULT_NEGATIVES]
    if len(extra) > 4:
        text += f" + {len(extra)} fixed negatives"
    elif extra:
        text += " + negatives " + ", ".join(extra)
    return text


def _given_by(h: Any) -> str:
    name = getattr(h, "name", "?")
    say = getattr(h, "information", None)
    if callable(say):
        return str(say())
    if name == "map-negatives" and getattr(h, "base", None) is not None:
        return _given_by(h.base) + " + map-mined negatives"
    if name == "auto":
        return "the label list, else the query + the shipped vocabulary"
    if name in ("taxonomy", "label-list"):
        file = getattr(h, "file", None)
        if file:
            return f"the label list ({Path(file).name})"
        if getattr(h, "taxonomy", None):
            return "the label list (in memory)"
        return "the label list (the map's label names)"
    if name == "combine":
        parts = [_given_by(getattr(h, k)) for k in ("_syn", "_ant") if getattr(h, k, None)]
        return " / ".join(dict.fromkeys(parts)) or "the query alone"
    return GIVEN.get(name, f"the query + heuristic {name}")


def _fmt(v: Any) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def report_markdown(
    configs: Sequence[dict[str, Any]], per_query: bool = True, title: str | None = None
) -> str:
    """Configs side by side: a summary table, then F1 per query (one column per config,
    and the ground-truth label when a query is not its label's name) and the items each
    absence query matched. With no present query the means are n/a, not 0."""
    lines = [f"### {title}", ""] if title else []
    lines += [
        "| method | given | F1 | precision | recall | IoU | AP | inv. rank | absence "
        "| present -> empty |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    scored = [c for c in configs if c.get("per_query")]
    best = max((c["mean"]["f1"] for c in scored), default=None)
    for c in configs:
        mean = c["mean"] if c.get("per_query") else {}
        f1 = _fmt(mean.get("f1"))
        if mean and mean["f1"] == best and len(scored) > 1:
            f1 = f"**{f1}**"
        ab = c.get("absence", {}) or {}
        n_present = len(c.get("per_query") or {})
        empty = ab.get("present_empty")
        lines.append(
            f"| {c['name']} | {c.get('given', '')} | {f1} | {_fmt(mean.get('precision'))} | "
            f"{_fmt(mean.get('recall'))} | {_fmt(mean.get('iou'))} | "
            f"{_fmt(mean.get('ap'))} | {_fmt(mean.get('inv_rank'))} | "
            f"{_fmt(ab.get('score'))} | "
            f"{'' if empty is None else f'{empty}/{n_present}' if n_present else empty} |"
        )
    if per_query and configs and configs[0]["per_query"]:
        label_of = {q: m.get("label", q) for q, m in configs[0]["per_query"].items()}
        show = any(q != label for q, label in label_of.items())
        lines += [
            "",
            "F1 per query:",
            "",
            "| query | "
            + ("label | " if show else "")
            + " | ".join(c["name"] for c in configs)
            + " |",
            "|---|" + ("---|" if show else "") + "---:|" * len(configs),
        ]
        for q, label in label_of.items():
            row = [_fmt(c["per_query"].get(q, {}).get("f1")) for c in configs]
            lines.append(f"| {q} | " + (f"{label} | " if show else "") + " | ".join(row) + " |")
    ab_q = list((configs[0].get("absence") or {}).get("per_query", {})) if configs else []
    if per_query and ab_q:
        tol = int((configs[0].get("absence") or {}).get("empty_tolerance") or 0)
        correct = f"at most {tol} = correct" if tol else "0 = correct"
        ab_label = {q: configs[0]["absence"]["per_query"][q].get("label", "") for q in ab_q}
        show = any(label and label != q for q, label in ab_label.items())
        lines += [
            "",
            f"Items matched by absence queries ({correct}):",
            "",
            "| absence query | "
            + ("label | " if show else "")
            + " | ".join(c["name"] for c in configs)
            + " |",
            "|---|" + ("---|" if show else "") + "---:|" * len(configs),
        ]
        for q in ab_q:
            row = [str(c["absence"]["per_query"][q]["matched"]) for c in configs]
            label = f"{ab_label[q]} | " if show else ""
            lines.append(f"| {q} | {label}" + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


__all__ = [
    "DEFAULT_EXCLUDE",
    "METRICS",
    "RANKING",
    "EvalReport",
    "eval_provenance",
    "evaluate",
    "given",
    "load_query_file",
    "parse_queries",
    "plan_queries",
    "report_markdown",
]


def is_report_file(path: str | Path) -> bool:
    """True when ``path`` is a report that ``quash eval``, ``bench`` or ``demo`` wrote.

    A JSON report holds ``{"configs": [...]}`` (eval, demo) or one such entry per table
    (bench); a Markdown report starts with ``# quash``. Such a file may be replaced by a
    new report without ``--force``; anything else may not.
    """
    import json

    p = Path(path)
    try:
        if p.suffix.lower() == ".json":
            with open(p, encoding="utf-8") as f:
                data = json.load(f)
            if not isinstance(data, dict) or not data:
                return False
            if isinstance(data.get("configs"), list):
                return True
            return all(
                isinstance(v, dict) and isinstance(v.get("configs"), list) for v in data.values()
            )
        with open(p, encoding="utf-8") as f:
            return f.readline().startswith("# quash ")
    except (OSError, UnicodeDecodeError, ValueError):
        return False
