"""``lexicon`` heuristic: random English words (the paper's random baseline)."""

from __future__ import annotations

from ..core.errors import ConfigError
from ..core.interfaces import ExpansionContext, Heuristic
from ..core.types import QuerySet
from ._data import read_word_list


class LexiconHeuristic(Heuristic):
    """Random words from a word list as synonyms and/or antonyms.

    The shipped list (``quash_plugins/data/lexicon.txt``) holds 3,000 common English
    words taken from the CLIP BPE vocabulary. Synonyms and antonyms never share a word
    and never contain the query. The draw depends on the seed and the query.

    Parameters
    ----------
    n_synonyms, n_antonyms
        How many random words on each side (the paper: 20 and 20). 0 turns a side off.
    file
        A word list (one word a line, or a YAML list); default the shipped one.
    """

    name = "lexicon"

    def __init__(self, n_synonyms: int = 20, n_antonyms: int = 20, file: str | None = None) -> None:
        self.n_synonyms = int(n_synonyms)
        self.n_antonyms = int(n_antonyms)
        self.file = file
        if self.n_synonyms < 0 or self.n_antonyms < 0:
            raise ConfigError("Heuristic 'lexicon': n_synonyms and n_antonyms must be >= 0.")
        option = (
            "The lexicon heuristic's 'file' option names it: give a word list (one word a "
            "line, or a YAML list), or leave it out to use the shipped one."
        )
        self._words = read_word_list(file, "lexicon.txt", "lexicon", option=option)

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        ctx = context or ExpansionContext()
        pool = [w for w in self._words if w.lower() != query.lower()]
        need = self.n_synonyms + self.n_antonyms
        if need > len(pool):
            raise ConfigError(
                f"Heuristic 'lexicon': asked for {need} words but the list has {len(pool)}."
            )
        idx = ctx.rng(f"lexicon|{query}").choice(len(pool), size=need, replace=False)
        words = [pool[i] for i in idx]
        syn, ant = words[: self.n_synonyms], words[self.n_synonyms :]
        return QuerySet(query, [query, *syn], ant, self.provenance(context, lexicon_size=len(pool)))

    def params(self) -> dict:
        return {"n_synonyms": self.n_synonyms, "n_antonyms": self.n_antonyms, "file": self.file}
