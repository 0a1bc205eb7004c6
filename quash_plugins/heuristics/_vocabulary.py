"""``vocabulary`` heuristic: nearest names of a shipped vocabulary, embedded once.

No language model and no network: the active encoder embeds the vocabulary (through the
text-embedding cache, and memoised in the process), and the query's neighbours in that
space become positives while near-but-distinct and far names become negatives.
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import ConfigError, HeuristicError
from ..core.interfaces import Encoder, ExpansionContext, Heuristic
from ..core.types import QuerySet
from ._data import read_word_list

log = logging.getLogger(__name__)

_MEMO: dict[tuple[str, str], np.ndarray] = {}
_MEMO_MAX = 8


#: What to give a missing vocabulary file (after "The ... option names it: ").
VOCABULARY_FIX = "give a file of names (one a line, or a YAML list)"


def load_vocabulary(
    spec: str | Sequence[str] | None = None,
    option: str = (
        f"The heuristic's 'vocabulary' option names it: {VOCABULARY_FIX}, or leave it out "
        "to use the shipped vocabulary."
    ),
) -> list[str]:
    """Vocabulary names: the shipped list (1,000+ everyday names), a list or a file.

    ``option``: a sentence naming the option that named the file and what to give it,
    said when the file is missing.
    """
    spec = spec if not isinstance(spec, tuple) else list(spec)
    return read_word_list(spec, "vocabulary.txt", "vocabulary", option=option)


def vocabulary_embeddings(encoder: Encoder, names: Sequence[str], cache: Any = None) -> np.ndarray:
    """``(V, D)`` float32 unit rows for ``names``; embedded once per encoder and process."""
    from ..core.text import encode_texts

    digest = hashlib.sha256("\n".join(names).encode()).hexdigest()[:16]
    key = (encoder.fingerprint(), digest)
    if key not in _MEMO:
        log.info("embedding a vocabulary of %d names with %s", len(names), encoder.name)
        if len(_MEMO) >= _MEMO_MAX:
            _MEMO.pop(next(iter(_MEMO)))
        _MEMO[key] = encode_texts(encoder, list(names), cache)
    return _MEMO[key]


def head_word(text: str) -> str:
    """The last word, lower-case: the head noun of an English noun phrase."""
    words = text.lower().split()
    return words[-1] if words else ""


class VocabularyHeuristic(Heuristic):
    """Positives: vocabulary names nearest the query; negatives: near-but-distinct + far.

    Similarities are cosines of the active encoder's text embeddings; the defaults suit
    sentence encoders such as MiniLM. CLIP-like text towers put every pair of nouns
    closer (0.7-0.9), so raise ``min_similarity`` and the band for them.

    Parameters
    ----------
    n_positives
        At most this many nearest names (besides the query) ...
    min_similarity
        ... each with cosine >= this.
    negative_band
        ``[low, high]``: "near" negatives have cosine in this band (below the positives,
        leaving a gap of ambiguous names out of the training set).
    n_near
        How many near negatives (the most similar names in the band).
    n_far
        How many far negatives, spread evenly over the names below the band.
    vocabulary
        The shipped list by default, else a file (one name a line, or a YAML list).
    names
        The vocabulary given in memory.

    negatives
        ``"band"`` (the near and far negatives above) or ``"all"``: the vocabulary stands
        in for a label list, and every name whose cosine to the query and to every
        positive is below ``exclude`` is a negative (each its own competitor in the
        presence check). The query is looked up in its normalised form
        (``normalise_name``: "fridge freezers" -> "fridge freezer").
    exclude
        With ``negatives: all``: names at least this close to a positive are left out.
    head_positives
        Also add up to this many names sharing the query's head noun as positives
        ("desk chair", "armchair" for "swivel chairs"; 0: none).

    Names ending with the query's head word (``"armchair"`` for ``"chair"``) are never
    negatives.
    """

    name = "vocabulary"

    def __init__(
        self,
        n_positives: int = 12,
        min_similarity: float = 0.65,
        negative_band: Sequence[float] = (0.35, 0.55),
        n_near: int = 20,
        n_far: int = 10,
        vocabulary: str | None = None,
        names: Sequence[str] | None = None,
        negatives: str = "band",
        exclude: float = 0.5,
        head_positives: int = 0,
    ) -> None:
        if negatives not in ("band", "all"):
            raise ConfigError(
                f"Heuristic 'vocabulary': negatives must be 'band' or 'all'; got {negatives!r}."
            )
        if int(head_positives) < 0:
            raise ConfigError("Heuristic 'vocabulary': 'head_positives' must be >= 0.")
        self.negatives = negatives
        self.exclude = float(exclude)
        self.head_positives = int(head_positives)
        if vocabulary is not None and names is not None:
            raise ConfigError("Heuristic 'vocabulary' takes 'vocabulary' or 'names', not both.")
        band = [float(x) for x in negative_band]
        if len(band) != 2 or band[0] > band[1]:
            raise ConfigError(
                f"Heuristic 'vocabulary': negative_band must be [low, high] with low <= high; "
                f"got {list(negative_band)!r}."
            )
        if band[1] > float(min_similarity):
            raise ConfigError(
                "Heuristic 'vocabulary': negative_band's upper end must not exceed "
                f"min_similarity ({min_similarity}); got {band[1]}."
            )
        for field, v in (("n_positives", n_positives), ("n_near", n_near), ("n_far", n_far)):
            if int(v) < 0:
                raise ConfigError(f"Heuristic 'vocabulary': {field!r} must be >= 0.")
        self.n_positives = int(n_positives)
        self.min_similarity = float(min_similarity)
        self.negative_band = band
        self.n_near = int(n_near)
        self.n_far = int(n_far)
        self.vocabulary = vocabulary
        self.names = list(names) if names is not None else None
        self._names = load_vocabulary(self.names if names is not None else vocabulary)

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        if context is None or context.encoder is None:
            raise HeuristicError(
                "Heuristic 'vocabulary' needs the encoder in its context (use it through "
                "Quash, or pass ExpansionContext(encoder=...))."
            )
        from ..core.text import encode_texts
        from ._taxonomy import normalise_name

        cache = context.extra.get("cache")
        V = vocabulary_embeddings(context.encoder, self._names, cache)
        lookup = normalise_name(query) or query if self.negatives == "all" else query
        q = encode_texts(context.encoder, [lookup], cache)[0]
        sims = V @ q
        order = np.argsort(-sims, kind="stable")
        qlow, head = query.lower(), head_word(lookup)
        pos: list[str] = []
        for i in order:
            if len(pos) >= self.n_positives or sims[i] < self.min_similarity:
                break
            if self._names[i].lower() != qlow:
                pos.append(self._names[i])
        if self.head_positives and head:
            same = [
                self._names[i]
                for i in order
                if head_word(self._names[i]) == head
                and self._names[i].lower() != qlow
                and self._names[i] not in pos
            ]
            pos += same[: self.head_positives]
        if lookup.lower() != qlow and lookup not in pos:
            pos.insert(0, lookup)
        taken = {qlow, *(p.lower() for p in pos)}

        def allowed(i: int) -> bool:
            n = self._names[i].lower()
            return n not in taken and not (head and n.endswith(head))

        if self.negatives == "all":
            P = encode_texts(context.encoder, [query, *pos], cache)
            close = (V @ P.T).max(axis=1) >= self.exclude
            neg = [self._names[i] for i in range(len(self._names)) if not close[i] and allowed(i)]
            prov = self.provenance(
                context,
                vocabulary_size=len(self._names),
                similarity={
                    self._names[i]: round(float(sims[i]), 3) for i in order[: self.n_positives]
                },
                negatives_all=len(neg),
            )
            return QuerySet(query, [query, *pos], neg, prov)
        low, high = self.negative_band
        near = [i for i in order if low <= sims[i] < high and allowed(i)][: self.n_near]
        far_pool = [i for i in order if sims[i] < low and allowed(i)]
        far: list[int] = []
        if self.n_far and far_pool:
            picks = np.linspace(0, len(far_pool) - 1, min(self.n_far, len(far_pool)))
            far = [far_pool[int(round(p))] for p in picks]
        if not pos:
            log.info(
                "vocabulary: no name within cosine %.2f of %r; positives are the query",
                self.min_similarity,
                query,
            )
        prov = self.provenance(
            context,
            vocabulary_size=len(self._names),
            similarity={
                self._names[i]: round(float(sims[i]), 3) for i in order[: self.n_positives]
            },
            near=len(near),
            far=len(far),
        )
        return QuerySet(query, [query, *pos], [self._names[i] for i in near + far], prov)

    def params(self) -> dict[str, Any]:
        return {
            "n_positives": self.n_positives,
            "min_similarity": self.min_similarity,
            "negative_band": self.negative_band,
            "n_near": self.n_near,
            "n_far": self.n_far,
            "negatives": self.negatives,
            "exclude": self.exclude,
            "head_positives": self.head_positives,
            "vocabulary": self.vocabulary if self.names is None else f"{len(self.names)} names",
        }
