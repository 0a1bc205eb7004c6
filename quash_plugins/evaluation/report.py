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

from ..core.errors import QuashError
from ..core.types import LatentMap

# the query plan, the provenance and "given", the Markdown tables and report files live
# in _plan, _provenance and _markdown; every name this module had is importable from it
from ._markdown import is_report_file as is_report_file
from ._markdown import report_markdown
from ._plan import DEFAULT_EXCLUDE, first_label_of, plan_queries
from ._plan import missing_ground_truth as missing_ground_truth
from ._provenance import GIVEN as GIVEN
from ._provenance import eval_provenance, given
from .metrics import METRICS, RANKING, absence_score, macro_mean, query_metrics
from .metrics import valid_items as valid_items
from .queries import label_key as label_key
from .queries import load_query_file, parse_queries
from .queries import match_labels as match_labels
from .queries import one_per_spelling as one_per_spelling
from .queries import say_twice as say_twice
from .queries import spelling as spelling
from .queries import warn_scored_absent as warn_scored_absent

log = logging.getLogger(__name__)


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
    index = first_label_of(lmap.label_names)
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
