"""The Markdown query-set document shown next to the 3D view."""

from __future__ import annotations

from collections.abc import Sequence

from ..core.types import LatentMap, QueryResult

_STAGES = ("read", "expand", "encode", "fit", "classify", "postprocess", "instances", "total")


def _md(text: object) -> str:
    """Escape the Markdown characters that would change how a word renders."""
    out = str(text)
    for ch in "\\`*_[]<>#|":
        out = out.replace(ch, "\\" + ch)
    return out


def queryset_markdown(
    lmap: LatentMap, result: QueryResult, index: int, notes: Sequence[str] = ()
) -> str:
    """Markdown for one result: query, positives, negatives, provenance, classifier,
    timings and any display-thinning note."""
    import yaml

    qs = result.queryset
    lines = [
        f"# {_md(qs.query)}",
        "",
        f"Query {index} · config **{_md(result.config_name or '-')}** · "
        f"matched **{result.n_matched:,}** of {lmap.n:,} items ({100 * result.share:.2f} %) · "
        f"{len(result.instances)} instances",
        "",
        f"Classifier: `{result.classifier or '-'}` · threshold {result.threshold:g}",
        "",
        f"## Positives ({len(qs.positives)})",
        "",
        *[f"- {_md(p)}" for p in qs.positives],
        "",
        f"## Negatives ({len(qs.negatives)})",
        "",
        *[f"- {_md(n)}" for n in qs.negatives],
        "",
        "## Provenance",
        "",
        "```yaml",
        yaml.safe_dump(qs.to_dict()["provenance"] or {}, sort_keys=False).rstrip(),
        "```",
        "",
    ]
    if result.timings:
        lines += ["## Timings", "", "| stage | ms |", "|---|---:|"]
        keys = [k for k in _STAGES if k in result.timings]
        keys += sorted(k for k in result.timings if k not in _STAGES)
        lines += [f"| {k} | {1000 * float(result.timings[k]):.1f} |" for k in keys]
        lines.append("")
    lines += ["## Map", "", _md(lmap.describe()), ""]
    if notes:
        lines += ["## Display", ""]
        lines += [f"- {n}" for n in notes]
        lines.append("")
    return "\n".join(lines)
