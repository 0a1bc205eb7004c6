"""What an evaluation scored (:func:`eval_provenance`, a report's ``provenance``) and
what each method was given besides the map (:func:`given`, a table's "given" column).
Public through :mod:`quash_plugins.evaluation.report`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.types import LatentMap
from ._plan import DEFAULT_EXCLUDE


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
