"""Query lists for evaluation: ``TEXT=LABEL`` items and query files.

``quash eval --queries "bunk bed=bed,chair"`` and ``--queries-file Q.yaml`` name each
query with its ground-truth label; :func:`parse_queries` and :func:`load_query_file`
read them into ``{query text: label}`` (and a list of absence queries).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..core.errors import QuashError


def parse_queries(queries: Any) -> dict[str, str]:
    """``{query text: ground-truth label}`` from labels, ``"text=label"`` items or a mapping.

    >>> parse_queries(["chair", "bunk bed=bed", "somewhere to sleep = bed"])
    {'chair': 'chair', 'bunk bed': 'bed', 'somewhere to sleep': 'bed'}
    """
    if isinstance(queries, dict):
        items = [(str(k), str(v)) for k, v in queries.items()]
    else:
        items = []
        for q in queries:
            text, sep, label = str(q).partition("=")
            items.append((text, label if sep else text))
    out: dict[str, str] = {}
    for text, label in items:
        text, label = " ".join(text.split()), " ".join(label.split())
        if not text or not label:
            raise QuashError(
                f"Query {text or label!r}: write an open-vocabulary query as TEXT=LABEL "
                "(e.g. 'bunk bed=bed'), with neither side empty."
            )
        out[text] = label
    return out


def load_query_file(path: str | Path) -> tuple[dict[str, str], list[str]]:
    """Presence queries ``{text: label}`` and absence queries from a YAML file.

    The file is ``{present: ..., absent: [...]}``; ``present`` is a list of labels and
    ``"text=label"`` items or a ``{text: label}`` mapping (``quash make-scene`` writes such
    files: ``SCENE.queries.yaml``, ``SCENE.open-queries.yaml``). A plain ``{text: label}``
    mapping without those keys is all presence queries.
    """
    from ..core.config import load_yaml

    data, _ = load_yaml(path)
    if isinstance(data, dict) and ("present" in data or "absent" in data):
        present, absent = data.get("present") or [], data.get("absent") or []
    elif isinstance(data, (dict, list)):
        present, absent = data, []
    else:
        raise QuashError(
            f"{path}: a query file is a mapping {{present: {{text: label}} or [labels], "
            "absent: [texts]}; see docs/evaluation.md."
        )
    if not isinstance(present, (dict, list)) or not isinstance(absent, list):
        raise QuashError(
            f"{path}: 'present' must be a list or a {{text: label}} mapping and 'absent' a "
            "list of texts."
        )
    return parse_queries(present), [" ".join(str(a).split()) for a in absent]


__all__ = ["load_query_file", "parse_queries"]
