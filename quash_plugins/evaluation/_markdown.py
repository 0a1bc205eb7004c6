"""A report's Markdown tables (:func:`report_markdown`), and whether a file is a report
quash wrote (:func:`is_report_file`). Public through
:mod:`quash_plugins.evaluation.report`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any


def _fmt(v: Any) -> str:
    return "n/a" if v is None else f"{v:.3f}"


def _per_query_head(first: str, label: bool, configs: Sequence[dict[str, Any]]) -> list[str]:
    """The header and rule of a table with a row per query: ``first``, a label column
    when ``label``, then one right-aligned column per config."""
    return [
        f"| {first} | "
        + ("label | " if label else "")
        + " | ".join(c["name"] for c in configs)
        + " |",
        "|---|" + ("---|" if label else "") + "---:|" * len(configs),
    ]


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
        lines += ["", "F1 per query:", "", *_per_query_head("query", show, configs)]
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
            *_per_query_head("absence query", show, configs),
        ]
        for q in ab_q:
            row = [str(c["absence"]["per_query"][q]["matched"]) for c in configs]
            label = f"{ab_label[q]} | " if show else ""
            lines.append(f"| {q} | {label}" + " | ".join(row) + " |")
    return "\n".join(lines) + "\n"


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
