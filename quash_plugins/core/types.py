"""Core data types: :class:`LatentMap`, :class:`QuerySet`, :class:`QueryResult`.

Shapes are checked here, at the boundary, so that nothing deeper has to. The map side
(:class:`LatentMap`, :class:`FrameInfo`, a map's source inputs) lives in
:mod:`quash_plugins.core.latent_map` and is re-exported here.
"""

from __future__ import annotations

import logging
import math
import unicodedata
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import QuashError
from .latent_map import (
    MAP_KINDS,
    SOURCE_INPUTS,
    UP_AXES,
    UP_CHOICES,
    FrameInfo,
    LatentMap,
    MapKind,
    prepare_block,
    record_inputs,
    source_inputs,
    taxonomy_path_beside,
)
from .presence_text import presence_words

__all__ = [
    "DEFAULT_NEGATIVES",
    "MAP_KINDS",
    "SOURCE_INPUTS",
    "UP_AXES",
    "UP_CHOICES",
    "FrameInfo",
    "Instance",
    "LatentMap",
    "MapKind",
    "QueryResult",
    "QuerySet",
    "check_query",
    "escape_control",
    "is_control",
    "prepare_block",
    "record_inputs",
    "source_inputs",
    "taxonomy_path_beside",
]

log = logging.getLogger(__name__)

#: Generic negatives the paper always adds to the antonyms.
DEFAULT_NEGATIVES: tuple[str, ...] = ("other", "background", "nothing")


@dataclass
class QuerySet:
    """The expanded query: positives (semantic synonyms) and negatives (antonyms).

    ``provenance`` records how the set was made (heuristic, parameters, seed), so an
    experiment can be reproduced from the YAML alone.
    """

    query: str
    positives: list[str]
    negatives: list[str]
    provenance: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.query = check_query(self.query)
        self.positives = _dedupe(self.positives)
        self.negatives = [n for n in _dedupe(self.negatives) if n not in set(self.positives)]
        if not self.positives:
            raise QuashError(f"Query set for {self.query!r} has no positives.")

    def with_negatives(self, extra: Sequence[str]) -> QuerySet:
        """A copy with ``extra`` appended to the negatives (positives win on overlap)."""
        return QuerySet(
            self.query, list(self.positives), [*self.negatives, *extra], dict(self.provenance)
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "positives": list(self.positives),
            "negatives": list(self.negatives),
            "provenance": _plain(self.provenance),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> QuerySet:
        return cls(
            data["query"],
            list(data.get("positives", [])),
            list(data.get("negatives", [])),
            dict(data.get("provenance", {})),
        )

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(self.to_dict(), sort_keys=False, allow_unicode=True)


#: Format characters that reorder text on a terminal (bidirectional overrides).
_BIDI = frozenset("\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069")


def is_control(char: str) -> bool:
    """True for a control character (C0, DEL, C1) or a bidirectional override."""
    return unicodedata.category(char) == "Cc" or char in _BIDI


def escape_control(text: str) -> str:
    r"""``text`` with control characters written as escapes, safe to print on a terminal.

    Newlines and tabs are kept; every other control character (escape sequences,
    carriage returns, NUL, bidirectional overrides) is written as ``\xNN``/``\uNNNN``.

    Examples
    --------
    >>> escape_control("chair\x1b[31m")
    'chair\\x1b[31m'
    """

    def bad(c: str) -> bool:
        return c not in "\n\t" and is_control(c)

    if not any(bad(c) for c in text):
        return text
    return "".join(c.encode("unicode_escape").decode("ascii") if bad(c) else c for c in text)


#: The longest query :func:`check_query` takes, in characters.
MAX_QUERY_CHARS = 1000


def check_query(text: Any) -> str:
    """Collapse a query's white space; reject empty queries and control characters.

    Tabs and newlines count as spaces. Any other control character (an escape sequence
    that would drive the terminal, a NUL that C code would cut the text at, a
    bidirectional override) is refused with its position, never silently dropped. A
    query longer than :data:`MAX_QUERY_CHARS` is refused (one of 120,000 characters was
    printed whole in every table and log line).
    """
    if not isinstance(text, str):
        raise QuashError(f"A query must be a string; got {type(text).__name__}.")
    stripped = " ".join(text.split())
    if not stripped:
        raise QuashError("The query is empty. Pass a word or phrase, e.g. 'chair'.")
    if len(stripped) > MAX_QUERY_CHARS:
        raise QuashError(
            f"The query is {len(stripped):,} characters long ('{escape_control(stripped[:40])}"
            f"...'); a query is a word or phrase, at most {MAX_QUERY_CHARS:,} characters "
            "(text encoders read far fewer: CLIP 77 tokens, MiniLM 256)."
        )
    bad = next((i for i, c in enumerate(stripped) if is_control(c)), None)
    if bad is not None:
        code = f"U+{ord(stripped[bad]):04X}"
        raise QuashError(
            f"The query '{escape_control(stripped)}' contains a control character ({code}) at "
            f"position {bad}. Queries are plain text: remove it."
        )
    return stripped


def _dedupe(items: Sequence[str]) -> list[str]:
    """Collapse white space and drop empty, repeated and control-character entries."""
    seen: set[str] = set()
    out = []
    for item in items:
        s = " ".join(str(item).split())
        if s and any(is_control(c) for c in s):
            log.warning("dropping %r from a query set: it holds control characters", s)
            continue
        if s and s not in seen:
            seen.add(s)
            out.append(s)
    return out


def _plain(obj: Any) -> Any:
    """Convert numpy scalars/arrays and tuples into YAML/JSON-friendly values."""
    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return obj


@dataclass
class Instance:
    """A connected group of matched items: what a robot navigates to.

    Attributes
    ----------
    id
        Its rank in :attr:`QueryResult.instances` (0 is the largest).
    indices
        ``(M,)`` int: the map's items (rows) it holds; ``size`` is ``M``.
    centroid
        ``(3,)`` float32: the mean position of its items, in metres in the map's frame
        (a pixel map without positions: pixel ``(col, row, 0)``).
    bbox_min, bbox_max
        ``(3,)`` float32: the corners of its axis-aligned box, in the same units.
    mean_score
        The mean raw score of its items.
    frame_id
        For a pixel map, the image it lies in; None otherwise.
    """

    id: int
    indices: np.ndarray
    centroid: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray
    mean_score: float
    frame_id: str | None = None

    @property
    def size(self) -> int:
        return int(len(self.indices))

    def __repr__(self) -> str:
        """One line (its size, centroid and mean score), not every index of its items."""
        centroid = ", ".join(f"{float(x):.3g}" for x in np.ravel(self.centroid))
        frame = f", frame_id={self.frame_id!r}" if self.frame_id is not None else ""
        return (
            f"Instance(id={self.id}, size={self.size}, centroid=[{centroid}], "
            f"mean_score={float(self.mean_score):.3f}{frame})"
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "size": self.size,
            "centroid": [float(x) for x in self.centroid],
            "bbox_min": [float(x) for x in self.bbox_min],
            "bbox_max": [float(x) for x in self.bbox_max],
            "mean_score": float(self.mean_score),
            "frame_id": self.frame_id,
        }


@dataclass
class QueryResult:
    """The answer to one query over one map.

    Row ``i`` of every ``(N,)`` array is item ``i`` of the map, in the order it was read
    (for a VLMaps map, row ``i`` of ``grid_feat``). To save results as ``quash query
    --out`` does, use :func:`quash_plugins.engine.write_results_npz`.

    Attributes
    ----------
    queryset
        The :class:`QuerySet` the classifier was trained on: the query, its positives
        and negatives, and its ``provenance`` (the heuristic and its parameters, the
        refinement, the presence check's decision).
    mask
        ``(N,)`` bool, True where the item matches.
    scores
        ``(N,)`` float32 raw decision values; ``mask == scores > threshold``.
    display_scores
        ``(N,)`` float32 in [0, 1], for colormaps; 0.5 at the threshold.
    threshold
        The score above which an item matches.
    instances
        The matched items in connected groups (:class:`Instance`), largest first; empty
        when nothing matched or the config groups none (``instances: false``, see
        :attr:`n_instances`).
    timings
        Seconds per stage (``read``, ``expand``, ``encode``, ``fit``, ``classify``, ...)
        and ``total``.
    classifier
        The classifier that decided, in words (with its refinement, if any).
    config_name
        The ``name`` of the config.
    map_source
        The map's record as its adapter read it (``adapter``, ``path``, ``up``...,
        ``inputs``: the files read for it, which ``write_results_npz`` never replaces).
    rejected
        ``(N,)`` bool: the items the last pass matched that the presence check dropped
        (what an absent object's look-alikes were); None when the config has no check.
    query
        The query text (``queryset.query``).
    n_matched
        How many items match.
    n_instances
        ``len(instances)``, or None when the config groups none.
    share
        ``n_matched / N``.
    presence
        The presence check's decision in words.
    emptied_by_presence
        Why the presence check emptied the mask, in words; None when it did not.
    under_threshold
        For an answer no item scored over the threshold for, the highest score against
        the threshold, in words; else None.
    """

    queryset: QuerySet
    mask: np.ndarray
    scores: np.ndarray
    display_scores: np.ndarray
    threshold: float = 0.0
    instances: list[Instance] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    classifier: str = ""
    config_name: str = ""
    map_source: dict[str, Any] = field(default_factory=dict)
    rejected: np.ndarray | None = None

    @property
    def query(self) -> str:
        return self.queryset.query

    @property
    def n_matched(self) -> int:
        return int(np.count_nonzero(self.mask))

    @property
    def n_instances(self) -> int | None:
        """How many instances were found; None when the config groups none
        (``instances: false``: the pipeline times the grouping only when it runs)."""
        if self.instances or "instances" in self.timings:
            return len(self.instances)
        return None

    @property
    def share(self) -> float:
        return self.n_matched / max(1, len(self.mask))

    @property
    def presence(self) -> str:
        """The presence check's decision in words: ``present``, ``absent: ...`` (why the
        mask is empty), ``not checked: ...`` or ``off`` (the config has no check)."""
        return presence_words(self.queryset.provenance)

    @property
    def emptied_by_presence(self) -> str | None:
        """The presence check's reason when it emptied the mask (matches it judged an
        absent object's look-alikes); None otherwise."""
        decision = self.presence
        if decision.startswith("absent: ") and decision != "absent: nothing matched":
            return decision.removeprefix("absent: ")
        return None

    @property
    def under_threshold(self) -> str | None:
        """When no item scored over the threshold, the highest score against it in words
        (the paper's SVM fitted on text alone often scores nothing over it); None when
        something matched or the presence check emptied the mask."""
        if self.n_matched or self.emptied_by_presence is not None:
            return None
        scores = np.asarray(self.scores)
        finite = scores[np.isfinite(scores)]
        if not finite.size:
            return None
        return f"its highest score is {float(finite.max()):.3g}, under the threshold {self.threshold:g}"

    def __repr__(self) -> str:
        """One line: the query, how many of the map's items matched, the instances and
        the presence decision; the arrays and the query set are the fields."""
        instances = "off" if self.n_instances is None else self.n_instances
        return (
            f"QueryResult(query={self.query!r}, matched={self.n_matched} of {len(self.mask)}, "
            f"instances={instances}, presence={self.presence!r}, config={self.config_name!r})"
        )

    def summary(self) -> dict[str, Any]:
        return {
            "query": self.query,
            "matched": self.n_matched,
            "share": self.share,
            "instances": self.n_instances,  # None when the config groups none, not 0
            "presence": self.presence,
            "timings": dict(self.timings),
        }
