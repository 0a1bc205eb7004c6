"""The Markdown query-set document shown next to the 3D view."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.types import LatentMap, QueryResult

_STAGES = (
    "read",
    "expand",
    "encode",
    "fit",
    "classify",
    "postprocess",
    "refine",
    "reclassify",
    "presence",
    "instances",
    "total",  # the sum of the stages above it: last
)
#: Stages done once for all the queries of a call (each query shows its equal share).
SHARED_STAGES = ("read", "encode", "classify", "reclassify")
#: Positives and negatives listed at the top of the document; the rest further down.
HEAD_ITEMS = 24


def _md(text: object) -> str:
    """Escape the Markdown characters that would change how a word renders."""
    out = str(text)
    for ch in "\\`*_[]<>#|":
        out = out.replace(ch, "\\" + ch)
    return out


def _head(words: Sequence[str], limit: int = HEAD_ITEMS) -> str:
    shown = ", ".join(_md(w) for w in words[:limit]) or "(none)"
    more = len(words) - limit
    return shown + (f" … and {more} more (listed below)" if more > 0 else "")


def _provenance_yaml(provenance: dict) -> str:
    """The provenance as YAML, lists of numbers (``negative_groups``) on one line."""
    import yaml

    class _Dumper(yaml.SafeDumper):
        pass

    def seq(dumper: yaml.SafeDumper, value: list) -> yaml.Node:
        flat = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", value, flow_style=flat)

    _Dumper.add_representer(list, seq)
    return yaml.dump(provenance, Dumper=_Dumper, sort_keys=False).rstrip()


def _instances_words(result: QueryResult) -> str:
    """``N instances``, or ``instances: off`` when the config groups none."""
    n = result.n_instances
    if n is None:
        return "instances: off"
    return f"{n} instance{'' if n == 1 else 's'}"


def queryset_markdown(
    lmap: LatentMap,
    result: QueryResult,
    index: int,
    notes: Sequence[str] = (),
    legend: Sequence[str] = (),
) -> str:
    """Markdown for one result: the query and its config, what matched, the map's colours
    by outcome when ground truth was given (``legend``: :func:`outcome_legend`), the
    positives and negatives (both at the top), classifier, timings, provenance and display
    notes."""

    qs = result.queryset
    config = result.config_name or "-"
    pos, neg = list(qs.positives), list(qs.negatives)
    lines = [
        f"# {_md(qs.query)} · {_md(config)}",
        "",
        f"Matched **{result.n_matched:,}** of {lmap.n:,} items ({100 * result.share:.2f} %) · "
        f"{_instances_words(result)} · query {index}",
        "",
        *legend,
        *_empty_words(result),
        f"Presence check: {_md(result.presence)}{_rejected_words(lmap, result)}",
        "",
        *_presence_detail(lmap, result),
        f"**Positives ({len(pos)}):** {_head(pos)}",
        "",
        f"**Negatives ({len(neg)}):** {_head(neg)}",
        "",
        f"Classifier: `{result.classifier or '-'}` · threshold {result.threshold:g} on its raw "
        "scores (0.5 in the score colours)",
        "",
    ]
    if result.timings:
        keys = [k for k in _STAGES if k in result.timings]
        keys += sorted(k for k in result.timings if k not in _STAGES)
        lines += ["## Timings", "", "| stage | ms |", "|---|---:|"]
        lines += [
            f"| {k}{' *' if k in SHARED_STAGES else ''} | {1000 * float(result.timings[k]):.1f} |"
            for k in keys
        ]
        lines += [
            "",
            "\\* done once for all the queries of the call; this is the query's equal share.",
            "",
        ]
    for title, words in (("All positives", pos), ("All negatives", neg)):
        if len(words) > HEAD_ITEMS:
            lines += [f"## {title} ({len(words)})", "", ", ".join(_md(w) for w in words), ""]
    lines += [
        "## Provenance",
        "",
        "```yaml",
        _provenance_yaml(qs.to_dict()["provenance"] or {}),
        "```",
        "",
        "## Map",
        "",
        _md(lmap.describe()),
        "",
    ]
    if notes:
        lines += ["## Display", ""]
        lines += [f"- {n}" for n in notes]
        lines.append("")
    return "\n".join(lines)


def outcome_legend(counts: Sequence[int], label: str | None = None) -> list[str]:
    """The legend of the map coloured by outcome: which colour is which, with the counts
    (``counts[k]``: the items of outcome ``k``, ``_display.OUTCOME_*``), as lines of the
    query's document."""
    from ._display import OUTCOME_FN, OUTCOME_FP, OUTCOME_TP, OUTCOME_UNSCORED, OUTCOME_WORDS

    against = f"the label {_md(label)}" if label else "no label of the map (an absence query)"
    parts = []
    for k in (OUTCOME_TP, OUTCOME_FP, OUTCOME_FN, OUTCOME_UNSCORED):
        if k == OUTCOME_UNSCORED and not counts[k]:
            continue
        colour, words = OUTCOME_WORDS[k]
        parts.append(f"**{colour}**: {words} {int(counts[k]):,}")
    return [f"Colours against {against}: " + " · ".join(parts), ""]


def _empty_words(result: QueryResult) -> list[str]:
    """Why an empty answer is empty when the presence line does not say: no item scored
    over the threshold (the presence check off, or nothing matched for it to judge)."""
    reason = result.under_threshold
    if reason is None:
        return []
    return [f"Nothing matched: {_md(reason)} (`threshold:` in the config sets it)", ""]


def _rejected_words(lmap: LatentMap, result: QueryResult) -> str:
    """How many matched items the presence check dropped, and where they are drawn grey:
    the map view (a map with positions), the image masks (a pixel map's frames)."""
    rejected = getattr(result, "rejected", None)
    n = int(np.count_nonzero(rejected)) if rejected is not None else 0
    if not n:
        return ""
    where = []
    if lmap.positions is not None:
        where.append("the map view")
    if lmap.kind == "pixels" and lmap.frames:
        where.append("the image masks")
    shown = f" (grey in {' and '.join(where)})" if where else ""
    return f" · dropped {n:,} matched item{'' if n == 1 else 's'}{shown}"


#: Labels named in the look-alike line (the rest are counted).
LOOKALIKE_LABELS = 6


def _presence_detail(lmap: LatentMap, result: QueryResult) -> list[str]:
    """Lines under the presence decision: the closest competitor of a present object (an
    absent one's is in its decision's words), and, on a map with labels, what the dropped
    items are: an absent object's look-alikes by name."""
    out = []
    info = (result.queryset.provenance or {}).get("presence")
    rival = info.get("rival") if isinstance(info, dict) else None
    if isinstance(rival, str) and rival and info.get("present"):
        out += [f"Closest competitor: {_md(rival)}", ""]
    rejected = getattr(result, "rejected", None)
    if rejected is None or lmap.labels is None or not np.any(rejected):
        return out
    labels = np.asarray(lmap.labels)[np.asarray(rejected, dtype=bool)]
    ids, counts = np.unique(labels[labels >= 0], return_counts=True)
    names = list(lmap.label_names or [])
    order = np.lexsort((ids, -counts))  # most first; ties by label id
    words = [
        f"{_md(names[i] if 0 <= i < len(names) else f'label {i}')} {n:,}"
        for i, n in zip(ids[order][:LOOKALIKE_LABELS], counts[order][:LOOKALIKE_LABELS])
    ]
    more = len(ids) - LOOKALIKE_LABELS
    unlabelled = int(np.count_nonzero(labels < 0))
    if unlabelled:
        words.append(f"unlabelled {unlabelled:,}")
    tail = f" … and {more} more label{'' if more == 1 else 's'}" if more > 0 else ""
    out += [f"Dropped items by the map's labels: {', '.join(words)}{tail}", ""]
    return out
