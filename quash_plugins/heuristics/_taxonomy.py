"""``taxonomy`` heuristic: the paper's "ground truth" from a label -> sub-classes file."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ..core.errors import ConfigError, HeuristicError, closest
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.types import QuerySet
from ._data import read_mapping

log = logging.getLogger(__name__)


def load_taxonomy(spec: str | dict | None) -> dict[str, list[str]]:
    """``{label: [sub-class, ...]}`` from a YAML file or a dict; ``null`` means no sub-classes."""
    data = read_mapping(spec, None, "taxonomy")
    where = spec if isinstance(spec, str) else "the taxonomy"
    out: dict[str, list[str]] = {}
    for label, subs in data.items():
        if subs is None:
            subs = []
        if not isinstance(subs, list):
            raise ConfigError(
                f"{where}: label {label!r} must map to a list of sub-classes (or be empty)."
            )
        key = " ".join(str(label).split())
        out[key] = list(dict.fromkeys(" ".join(str(s).split()) for s in subs if str(s).strip()))
    if not out:
        raise ConfigError(f"{where}: the taxonomy has no labels.")
    return out


class TaxonomyHeuristic(Heuristic):
    """Synonyms from the query label's sub-classes, antonyms from the other labels'.

    Parameters
    ----------
    file
        YAML ``{label: [sub-class, ...]}`` (e.g. Matterport3D's 40 labels with their
        1,659 fine classes). Without it, the map's label names are the taxonomy (labels
        without sub-classes).
    taxonomy
        The same mapping given in memory.
    n_synonyms
        Up to this many sub-classes of the query's label, sampled (the paper: 20).
    n_antonyms
        Up to this many sub-classes of the other labels, sampled (the paper: 100).
    include_other_labels
        Also count the other labels' own names as antonym candidates.
    resolve
        Resolve a query that is not a label to the nearest label by cosine similarity
        of the encoder's text embeddings (reported in provenance and the log). When
        False, such a query is an error.
    min_similarity
        A query whose nearest label has a lower cosine is not forced onto that label: it
        stays its own positive and every label's sub-classes are antonym candidates, so
        an object the taxonomy does not know ("an elephant") can come back empty.
    """

    name = "taxonomy"

    def __init__(
        self,
        file: str | None = None,
        taxonomy: dict[str, Any] | None = None,
        n_synonyms: int = 20,
        n_antonyms: int = 100,
        include_other_labels: bool = True,
        resolve: bool = True,
        min_similarity: float = 0.5,
    ) -> None:
        if file is not None and taxonomy is not None:
            raise ConfigError("Heuristic 'taxonomy' takes 'file' or 'taxonomy', not both.")
        self.file = file
        self.taxonomy = taxonomy
        self.n_synonyms = int(n_synonyms)
        self.n_antonyms = int(n_antonyms)
        self.include_other_labels = bool(include_other_labels)
        self.resolve = bool(resolve)
        self.min_similarity = float(min_similarity)
        if self.n_synonyms < 0 or self.n_antonyms < 0:
            raise ConfigError("Heuristic 'taxonomy': n_synonyms and n_antonyms must be >= 0.")
        spec = file if file is not None else taxonomy
        self._tax = load_taxonomy(spec) if spec is not None else None

    def _labels(self, context: ExpansionContext) -> dict[str, list[str]]:
        if self._tax is not None:
            return self._tax
        if context.label_names:
            return {str(n): [] for n in context.label_names}
        raise HeuristicError(
            "Heuristic 'taxonomy' has no taxonomy: give 'file' ({label: [sub-class, ...]}) "
            "or query a map that has label_names."
        )

    def resolve_label(
        self, query: str, context: ExpansionContext
    ) -> tuple[str | None, float | None]:
        """The taxonomy label for ``query`` and, when resolved by embedding, its cosine.

        The label is None when the nearest label is below ``min_similarity``.
        """
        tax = self._labels(context)
        low = {k.lower(): k for k in tax}
        if query.lower() in low:
            return low[query.lower()], None
        where = self.file or "the taxonomy"
        if not self.resolve or context.encoder is None:
            guess = closest(query, tax)
            hint = f" Did you mean {guess!r}?" if guess else ""
            why = "resolve is off" if not self.resolve else "no encoder to resolve it"
            raise HeuristicError(
                f"Query {query!r} is not a label of {where} ({why}).{hint} "
                f"Labels: {', '.join(list(tax)[:30])}{' ...' if len(tax) > 30 else ''}."
            )
        from ..core.text import encode_texts

        labels = list(tax)
        cache = context.extra.get("cache")
        E = encode_texts(context.encoder, labels, cache)
        q = encode_texts(context.encoder, [query], cache)[0]
        sims = E @ q
        best = int(np.argmax(sims))
        if float(sims[best]) < self.min_similarity:
            log.info(
                "taxonomy: query %r is not a label; nearest %r (cosine %.3f) is below "
                "min_similarity %.2f, so it is kept as its own concept",
                query,
                labels[best],
                float(sims[best]),
                self.min_similarity,
            )
            return None, float(sims[best])
        log.info(
            "taxonomy: query %r is not a label; resolved to %r (cosine %.3f)",
            query,
            labels[best],
            float(sims[best]),
        )
        return labels[best], float(sims[best])

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        tax = self._labels(ctx)
        label, sim = self.resolve_label(query, ctx)
        rng = ctx.rng(f"taxonomy|{label if label is not None else query}")
        own = tax[label] if label is not None else []
        syn = _sample(own, self.n_synonyms, rng)
        mine = {query.lower(), *(s.lower() for s in own)}
        if label is not None:
            mine.add(label.lower())
        pool: list[str] = []
        for other, subs in tax.items():
            if other == label:
                continue
            cands = ([other] if self.include_other_labels else []) + subs
            pool.extend(c for c in cands if c.lower() not in mine)
        pool = list(dict.fromkeys(pool))
        ant = _sample(pool, self.n_antonyms, rng)
        extra: dict[str, Any] = {"label": label}
        if sim is not None:
            extra["resolved"] = {"from": query, "to": label, "cosine": round(sim, 4)}
        positives = [query, label, *syn] if label is not None else [query]
        return QuerySet(query, positives, ant, self.provenance(context, **extra))

    def params(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "labels": len(self._tax) if self._tax is not None else None,
            "n_synonyms": self.n_synonyms,
            "n_antonyms": self.n_antonyms,
            "include_other_labels": self.include_other_labels,
            "resolve": self.resolve,
            "min_similarity": self.min_similarity,
        }


def _sample(items: list[str], n: int, rng: np.random.Generator) -> list[str]:
    if len(items) <= n:
        return list(items)
    idx = rng.choice(len(items), size=n, replace=False)
    return [items[i] for i in sorted(idx.tolist())]
