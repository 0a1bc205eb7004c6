"""``adjectives`` heuristic: the query dressed in adjectives of distinct types."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.types import QuerySet
from ._data import read_mapping


def load_adjectives(file: str | dict | None = None) -> dict[str, list[str]]:
    """``{type: [adjective, ...]}`` in phrase order; the shipped list has 44 in 7 types."""
    option = (
        "The adjectives heuristic's 'file' option names it: give a YAML file of {type: "
        "[adjective, ...]} with at least 3 types, or leave it out to use the shipped list "
        "(quash_plugins/data/adjectives.yaml)."
    )
    data = read_mapping(file, "adjectives.yaml", "adjective list", option=option)
    where = file if isinstance(file, str) else "the adjective list"
    out: dict[str, list[str]] = {}
    seen: set[str] = set()
    for kind, words in data.items():
        if not isinstance(words, list) or not words:
            raise ConfigError(f"{where}: type {kind!r} must map to a non-empty list of adjectives.")
        clean = [" ".join(str(w).split()) for w in words]
        dup = [w for w in clean if w in seen]
        if dup:
            raise ConfigError(f"{where}: adjective {dup[0]!r} appears under more than one type.")
        seen.update(clean)
        out[str(kind)] = clean
    if len(out) < 3:
        raise ConfigError(f"{where}: needs at least 3 adjective types for 3-adjective phrases.")
    return out


def adjective_phrases(
    noun: str,
    adjectives: dict[str, list[str]],
    rng: np.random.Generator,
    n_double: int = 10,
    n_triple: int = 5,
) -> list[str]:
    """The bare noun, every single-adjective phrase, then random 2- and 3-adjective phrases.

    Multi-adjective phrases take each adjective from a different type, are distinct, and
    put adjectives in the order of the types in ``adjectives``.

    Examples
    --------
    >>> adj = {"colour": ["red"], "material": ["wooden", "metal"], "age": ["old"]}
    >>> adjective_phrases("chair", adj, np.random.default_rng(0), 0, 0)
    ['chair', 'red chair', 'wooden chair', 'metal chair', 'old chair']
    """
    kinds = list(adjectives)
    out = [noun] + [f"{a} {noun}" for k in kinds for a in adjectives[k]]
    for size, count in ((2, n_double), (3, n_triple)):
        out.extend(_combos(noun, adjectives, kinds, size, count, rng))
    return out


def _combos(noun, adjectives, kinds, size, count, rng) -> list[str]:
    from itertools import combinations
    from math import prod

    possible = sum(prod(len(adjectives[k]) for k in c) for c in combinations(kinds, size))
    if count > possible:
        raise ConfigError(f"Asked for {count} {size}-adjective phrases but only {possible} exist.")
    made: list[str] = []
    seen: set[tuple[str, ...]] = set()
    while len(made) < count:
        picked = sorted(rng.choice(len(kinds), size=size, replace=False).tolist())
        words = tuple(
            adjectives[kinds[i]][int(rng.integers(len(adjectives[kinds[i]])))] for i in picked
        )
        if words in seen:
            continue
        seen.add(words)
        made.append(" ".join([*words, noun]))
    return made


class AdjectivesHeuristic(Heuristic):
    """Positives: the query with adjectives; negatives: the same on ``"other"``.

    With the shipped list (44 adjectives, 7 types) each side has 1 + 44 + 10 + 5 = 60
    strings, as in the paper's "adjectives" ablation.

    Parameters
    ----------
    file
        YAML ``{type: [adjective, ...]}``; default the shipped list.
    n_double, n_triple
        How many random two- and three-adjective phrases.
    negative_noun
        The noun of the negatives (the paper: ``"other"``).
    positives, negatives
        Build that side (set ``negatives: false`` to use adjectives for synonyms only).
    """

    name = "adjectives"

    def __init__(
        self,
        file: str | None = None,
        n_double: int = 10,
        n_triple: int = 5,
        negative_noun: str = "other",
        positives: bool = True,
        negatives: bool = True,
    ) -> None:
        self.file = file
        self.n_double = int(n_double)
        self.n_triple = int(n_triple)
        self.negative_noun = str(negative_noun)
        self.positives = bool(positives)
        self.negatives = bool(negatives)
        if self.n_double < 0 or self.n_triple < 0:
            raise ConfigError("Heuristic 'adjectives': n_double and n_triple must be >= 0.")
        self._adjectives = load_adjectives(file)

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        pos = [query]
        if self.positives:
            pos = adjective_phrases(
                query,
                self._adjectives,
                ctx.rng(f"adjectives|{query}"),
                self.n_double,
                self.n_triple,
            )
        neg: list[str] = []
        if self.negatives:
            neg = adjective_phrases(
                self.negative_noun,
                self._adjectives,
                ctx.rng(f"adjectives-negative|{query}"),
                self.n_double,
                self.n_triple,
            )
        n_adj = sum(len(v) for v in self._adjectives.values())
        return QuerySet(
            query,
            pos,
            neg,
            self.provenance(context, adjectives=n_adj, types=list(self._adjectives)),
        )

    def params(self) -> dict[str, Any]:
        return {k: v for k, v in vars(self).items() if not k.startswith("_")}
