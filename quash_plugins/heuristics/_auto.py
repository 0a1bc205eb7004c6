"""``auto`` heuristic: the map's label list when it has one, else the shipped vocabulary.

This is the heuristic of the default config (``quash query MAP QUERY`` with no ``-c``,
``core.config.DEFAULT_CONFIG``). With a label list every other label is a competitor, so
the presence check can tell that an object is not there; without one, the shipped
vocabulary stands in for the list.
"""

from __future__ import annotations

import logging
from typing import Any

from ..core.interfaces import ExpansionContext, Heuristic
from ..core.once import first_time
from ..core.types import QuerySet
from ._taxonomy import TaxonomyHeuristic, taxonomy_beside, taxonomy_missing, unlisted_param
from ._vocabulary import VocabularyHeuristic

log = logging.getLogger(__name__)


class AutoHeuristic(Heuristic):
    """The label list of the map (or of ``file``), else the vocabulary as the list.

    - a ``file``, or a map with label names or a ``MAP.taxonomy.yaml`` beside it: the
      ``taxonomy`` heuristic with ``n_antonyms: all`` (the query's label and its
      sub-classes against every other label with its sub-classes);
    - otherwise: the ``vocabulary`` heuristic with ``negatives: all`` (every vocabulary name
      not close to the query is a competitor) and names sharing the query's head noun as
      positives.

    ``unlisted`` is the label list's option of that name (off by default; see
    :class:`~quash_plugins.heuristics.TaxonomyHeuristic`). ``provenance["auto"]`` says
    which was used.
    """

    name = "auto"

    def __init__(
        self,
        file: str | None = None,
        n_synonyms: int = 20,
        exclude: float = 0.5,
        head_positives: int = 20,
        vocabulary: str | None = None,
        unlisted: str | list[str] | None = None,
    ) -> None:
        self.file = file
        self.unlisted = unlisted
        self.n_synonyms = int(n_synonyms)
        self.exclude = float(exclude)
        self.head_positives = int(head_positives)
        self.vocabulary = vocabulary
        self._labels = TaxonomyHeuristic(
            file=file, n_synonyms=n_synonyms, n_antonyms="all", unlisted=unlisted
        )
        self._vocab: VocabularyHeuristic | None = None

    def _vocabulary(self) -> VocabularyHeuristic:
        if self._vocab is None:
            self._vocab = VocabularyHeuristic(
                negatives="all",
                exclude=self.exclude,
                head_positives=self.head_positives,
                vocabulary=self.vocabulary,
            )
        return self._vocab

    def uses_label_list(self, context: ExpansionContext | None) -> bool:
        """True when a label list is known: ``file``, the map's names or a taxonomy beside it."""
        if self.file is not None:
            return True
        if context is None:
            return False
        return bool(context.label_names) or taxonomy_beside(context.map) is not None

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        if self.uses_label_list(ctx):
            qs, how = self._labels.expand(query, ctx), "label list"
        else:
            missing, misplaced = taxonomy_missing(ctx.map)
            if missing and first_time(("auto-vocabulary", missing)):
                log.log(
                    logging.WARNING if misplaced else logging.INFO,
                    "the map has no label names and no taxonomy beside it (%s): the shipped "
                    "vocabulary stands in for its label list",
                    missing,
                )
            qs, how = self._vocabulary().expand(query, ctx), "vocabulary"
        prov = dict(qs.provenance)
        prov["auto"] = how
        prov["heuristic"] = self.name
        prov["params"] = {**self.params(), "used": prov.get("params")}
        return QuerySet(qs.query, qs.positives, qs.negatives, prov)

    def params(self) -> dict[str, Any]:
        return {
            "file": self.file,
            "n_synonyms": self.n_synonyms,
            "exclude": self.exclude,
            "head_positives": self.head_positives,
            "vocabulary": self.vocabulary,
            "unlisted": unlisted_param(self.unlisted),
        }
