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
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..core.errors import QuashError
from ..core.types import LatentMap
from .metrics import METRICS, absence_score, macro_mean, query_metrics, valid_items

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
    """Scores of several configs on one map. ``configs`` is the JSON payload's list."""

    configs: list[dict[str, Any]]
    queries: list[str]
    absent: list[str]
    results: dict[str, list[Any]] = field(default_factory=dict, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {"configs": self.configs}

    def to_markdown(self, per_query: bool = True) -> str:
        return report_markdown(self.configs, per_query=per_query)

    def best(self, metric: str = "f1") -> dict[str, Any]:
        return max(self.configs, key=lambda c: c["mean"][metric])


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
) -> EvalReport:
    """Score each config once over all queries (one :meth:`Quash.query_many` pass each).

    Parameters
    ----------
    source
        A map path or a :class:`LatentMap` with ``labels`` and ``label_names``.
    configs
        Config paths, dicts, :class:`QuashConfig` or ready :class:`Quash` objects.
    queries
        Label names to score; None scores every label present in the map (minus
        ``exclude``). A listed label that no item carries becomes an absence query.
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
        Called as ``on_query(config_name, n_queries)`` after each config's pass.
    """
    overrides = dict(overrides or {})
    if not configs:
        raise QuashError("evaluate needs at least one config.")
    quashes = [_as_quash(c, overrides) for c in configs]
    lmap = source if isinstance(source, LatentMap) else quashes[0].read_map(source)
    if lmap.labels is None or not lmap.label_names:
        where = lmap.source.get("path", "the map")
        raise QuashError(
            f"{where} has no ground-truth labels (labels + label_names); "
            "evaluation needs them. Use a labelled map, e.g. `quash make-scene`."
        )
    labels = np.asarray(lmap.labels)
    names = list(lmap.label_names)
    valid = valid_items(labels, names, exclude)
    counts = (
        np.bincount(labels[valid], minlength=len(names))
        if valid.any()
        else np.zeros(len(names), int)
    )
    if queries is None:
        queries = [n for i, n in enumerate(names) if counts[i] > 0 and n not in set(exclude)]
    queries = list(dict.fromkeys(queries))
    unknown_here = [q for q in queries if q not in names or counts[names.index(q)] == 0]
    presence = [q for q in queries if q not in unknown_here]
    absence = list(dict.fromkeys([*unknown_here, *absent]))
    absence = [a for a in absence if a not in presence]
    if unknown_here:
        log.info(
            "labels absent from the map, scored as absence queries: %s", ", ".join(unknown_here)
        )
    if not presence and not absence:
        raise QuashError("No query to evaluate: the map has no label left after --exclude.")
    used: dict[str, int] = {}
    out, all_results = [], {}
    for quash, config in zip(quashes, configs):
        name = quash.name
        if name in used:
            used[name] += 1
            stem = Path(str(config)).stem if isinstance(config, (str, Path)) else str(used[name])
            name = f"{name} ({stem})"
        used.setdefault(name, 0)
        texts = [*presence, *absence]
        results = quash.query_many(lmap, texts)
        per_query = {}
        for q, r in zip(presence, results[: len(presence)]):
            truth = labels == names.index(q)
            per_query[q] = query_metrics(r.mask, truth, valid)
        masks = {q: r.mask for q, r in zip(texts, results)}
        ab = absence_score({q: masks[q] for q in absence}, valid, empty_tolerance)
        out.append(
            {"name": name, "mean": macro_mean(per_query), "per_query": per_query, "absence": ab}
        )
        if keep_results:
            all_results[name] = results
        if on_query is not None:
            on_query(name, len(texts))
    return EvalReport(out, presence, absence, all_results)


def _fmt(v: Any) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def report_markdown(
    configs: Sequence[dict[str, Any]], per_query: bool = True, title: str | None = None
) -> str:
    """Configs side by side: a summary table, then F1 per query (one column per config)."""
    lines = [f"### {title}", ""] if title else []
    lines += [
        "| method | F1 | precision | recall | IoU | absence |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    best = max((c["mean"]["f1"] for c in configs), default=0.0)
    for c in configs:
        f1 = _fmt(c["mean"]["f1"])
        if c["mean"]["f1"] == best and len(configs) > 1:
            f1 = f"**{f1}**"
        ab = c.get("absence", {}) or {}
        lines.append(
            f"| {c['name']} | {f1} | {_fmt(c['mean']['precision'])} | "
            f"{_fmt(c['mean']['recall'])} | {_fmt(c['mean']['iou'])} | "
            f"{_fmt(ab.get('score'))} |"
        )
    if per_query and configs and configs[0]["per_query"]:
        lines += [
            "",
            "F1 per query:",
            "",
            "| query | " + " | ".join(c["name"] for c in configs) + " |",
            "|---|" + "---:|" * len(configs),
        ]
        for q in configs[0]["per_query"]:
            row = [_fmt(c["per_query"].get(q, {}).get("f1")) for c in configs]
            lines.append(f"| {q} | " + " | ".join(row) + " |")
        ab_q = list((configs[0].get("absence") or {}).get("per_query", {}))
        if ab_q:
            lines += [
                "",
                "Items matched by absence queries (0 = correct):",
                "",
                "| absence query | " + " | ".join(c["name"] for c in configs) + " |",
                "|---|" + "---:|" * len(configs),
            ]
            for q in ab_q:
                row = [str(c["absence"]["per_query"][q]["matched"]) for c in configs]
                lines.append(f"| {q} | " + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


__all__ = [
    "DEFAULT_EXCLUDE",
    "METRICS",
    "EvalReport",
    "evaluate",
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
