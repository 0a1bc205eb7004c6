"""A query's presence decision in words: :attr:`QueryResult.presence
<quash_plugins.core.types.QueryResult.presence>` and the ``presence`` line of
``quash query --json``.

The engine's presence check (:mod:`quash_plugins.engine.presence`) records its decision
in ``provenance["presence"]``; this module only reads that record, so the core can say
why a query came back empty without importing the engine.

Examples
--------
>>> presence_words({})
'off'
>>> presence_words({"presence": {"checked": True, "present": True, "kept": 1, "components": 3}})
'present (1 of 3 components kept)'
"""

from __future__ import annotations

from typing import Any

__all__ = ["presence_words"]


def presence_words(provenance: dict[str, Any]) -> str:
    """A query set's presence decision (``provenance["presence"]``) in words; see
    :attr:`QueryResult.presence`."""
    info = provenance.get("presence")
    if not isinstance(info, dict):
        return "off"
    if not info.get("checked", True):
        return f"not checked: {info.get('why', 'no neighbourhood')}"
    if info.get("present"):
        kept = f"{info.get('kept', 0)} of {info.get('components', 0)} components kept"
        return f"present ({kept}{_reseed_words(info)})"
    best = [
        f"{what} {info[key]:+.3f}"
        for key, what in (
            ("best_margin", "grown region"),
            ("best_core_margin", "own items"),
            ("best_support_margin", "own items against the support"),
        )
        if isinstance(info.get(key), (int, float))
    ]
    n = info.get("components")
    if not n:
        return f"absent: nothing matched{_unresolved(provenance, None)}"
    if not best:
        return f"absent: {_no_large_component(info, int(n))}{_unresolved(provenance, None)}"
    rival = info.get("rival")
    against = f"; closest competitor: {rival!r}" if isinstance(rival, str) and rival else ""
    return (
        "absent: no component won clearly against the other labels "
        f"(best margins: {', '.join(best)}{against}{_reseed_words(info)})"
        f"{_unresolved(provenance, rival)}"
    )


def _reseed_words(info: dict[str, Any]) -> str:
    """What the check's second refit (``presence.reseed``) did, when it ran one.

    Examples
    --------
    >>> _reseed_words({"reseed": {"first_pass_present": True, "first_pass_kept": 12,
    ...                           "positives": 12, "present": True}})
    '; found by a second refit on the 12 items the first pass kept'
    >>> _reseed_words({"reseed": {"first_pass_present": True, "first_pass_kept": 140,
    ...                           "positives": 100, "present": False}})
    '; a second refit on the 100 of the 140 items the first pass kept found none either'
    >>> _reseed_words({"reseed": {"first_pass_present": False, "present": False}})
    ''
    """
    record = info.get("reseed")
    if not isinstance(record, dict) or not isinstance(record.get("positives"), int):
        return ""
    n, kept = record["positives"], record.get("first_pass_kept", record["positives"])
    items = f"{n} items" if n == kept else f"{n} of the {kept} items"
    if record.get("present"):
        return f"; found by a second refit on the {items} the first pass kept"
    return f"; a second refit on the {items} the first pass kept found none either"


def _unresolved(provenance: dict[str, Any], rival: Any) -> str:
    """For an empty answer to a query that resolved to no label: the label it was nearest
    to and, when that label is also what beat it in the map, how to ask for it."""
    res = provenance.get("resolved")
    if not isinstance(res, dict) or res.get("how") != "none" or not res.get("nearest"):
        return ""
    near, cos = res["nearest"], res.get("cosine")
    least = res.get("min_similarity")
    told = f"cosine {cos}" + (f" < min_similarity {least}" if least is not None else "")
    words = f"; the query resolved to no label (nearest: {near!r}, {told})"
    if rival == near:
        words += (
            f", and what matched it is nearer {near!r} itself: if you meant {near!r}, ask "
            "for it by name, lower min_similarity, or expand with an LLM heuristic"
        )
    return words


def _no_large_component(info: dict[str, Any], n: int) -> str:
    """Why no component was weighed: all are smaller than ``min_component``, else the
    flat margin left none (older provenance, without the sizes: in general words)."""
    largest, least = info.get("largest_component"), info.get("min_component")
    if not isinstance(largest, int) or not isinstance(least, int):
        return "no component large enough"
    if largest < least:
        items = f"{largest} item{'' if largest == 1 else 's'}"
        if n == 1:
            return f"the only component ({items}) is smaller than min_component={least}"
        return f"all {n} components are smaller than min_component={least} (largest: {items})"
    return (
        f"no component of at least min_component={least} items beat every negative by flat_margin"
    )
