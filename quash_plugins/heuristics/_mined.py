"""Map-mined negatives: vocabulary names that many map items match best.

For any heuristic, when a map is given (config ``map_negatives: {...}``), the names of a
vocabulary that win the argmax over a random sample of the map's items, but are not the
query or its positives (nor too similar to them), are added as negatives: they are the
concepts really present in this scene.

It is a heuristic wrapper, ``map-negatives``, registered like every other heuristic: the
pipeline wraps the configured heuristic in it when ``map_negatives`` is set.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..core.errors import ConfigError
from ..core.interfaces import Encoder, ExpansionContext, Heuristic
from ..core.types import LatentMap, QuerySet, prepare_block

log = logging.getLogger(__name__)


def add_map_negatives(
    qs: QuerySet,
    lmap: LatentMap,
    encoder: Encoder,
    cache: Any = None,
    n: int = 5,
    min_share: float = 0.01,
    vocabulary: str | Sequence[str] | None = None,
    sample: int = 20000,
    max_similarity: float = 0.8,
    chunk: int = 4096,
    seed: int = 0,
    **unknown: Any,
) -> QuerySet:
    """Return ``qs`` with up to ``n`` map-mined negatives added (provenance records them).

    Parameters
    ----------
    qs
        The expanded query set.
    lmap
        The map; ``sample`` random rows (sorted, read in chunks of ``chunk`` rows) are
        scored, normalised when ``lmap.normalize``; zero rows are ignored.
    encoder, cache
        Embed the vocabulary, the query and the positives.
    n
        At most this many names are added, most frequent first.
    min_share
        A name must win at least this fraction of the observed sampled items.
    vocabulary
        The shipped vocabulary by default, a file or a list of names.
    max_similarity
        Names with cosine >= this to the query or any positive are never added.
    seed
        Seed of the row sample.

    The query and positives take part in the argmax, so items that look like the query
    are credited to it, not to a rival name.
    """
    if unknown:
        raise ConfigError(
            f"map_negatives does not accept {sorted(unknown)}; it takes n, min_share, "
            "vocabulary, sample, max_similarity, chunk and seed."
        )
    if int(n) <= 0:
        return qs
    from ..core.text import encode_texts
    from ._vocabulary import VOCABULARY_FIX, load_vocabulary, vocabulary_embeddings

    option = (
        f"The 'vocabulary' option of map_negatives names it: {VOCABULARY_FIX}, or leave it "
        "out to use the shipped vocabulary."
    )
    names = load_vocabulary(vocabulary, option)
    V = vocabulary_embeddings(encoder, names, cache)
    P = encode_texts(encoder, list(qs.positives), cache)
    if V.shape[1] != lmap.dim:
        raise ConfigError(
            f"map_negatives: encoder {encoder.name!r} is {V.shape[1]}-d but the map is "
            f"{lmap.dim}-d."
        )
    cands = np.concatenate([P, V]).astype(np.float32)
    rng = np.random.default_rng(int(seed))
    size = min(int(sample), lmap.n)
    rows = np.sort(rng.choice(lmap.n, size=size, replace=False)) if size < lmap.n else None
    wins = np.zeros(len(cands), dtype=np.int64)
    observed = 0
    step = max(1, int(chunk))
    total = size if rows is not None else lmap.n
    for start in range(0, total, step):
        if rows is not None:
            idx = rows[start : start + step]
            block = np.asarray(lmap.embeddings[idx], dtype=np.float32)
        else:
            block = np.asarray(lmap.embeddings[start : start + step], dtype=np.float32)
        block = prepare_block(np.array(block, copy=True), start, lmap.normalize, lmap.source)
        live = np.any(block != 0, axis=1)
        if not live.any():
            continue
        best = np.argmax(block[live] @ cands.T, axis=1)
        wins += np.bincount(best, minlength=len(cands))
        observed += int(live.sum())
    if observed == 0:
        log.warning("map_negatives: no observed (non-zero) rows in the sample; nothing mined")
        return qs
    close = (V @ P.T).max(axis=1) >= float(max_similarity)
    taken = {s.lower() for s in (*qs.positives, *qs.negatives)}
    vw = wins[len(P) :]
    order = np.argsort(-vw, kind="stable")
    added: dict[str, float] = {}
    for i in order:
        share = vw[i] / observed
        if len(added) >= int(n) or share < float(min_share):
            break
        if close[i] or names[i].lower() in taken:
            continue
        added[names[i]] = round(float(share), 4)
    out = qs.with_negatives(list(added))
    out.provenance["map_negatives"] = {
        "added": list(added),
        "share": added,
        "query_share": round(float(wins[: len(P)].sum() / observed), 4),
        "sampled": int(total),
        "observed": observed,
        "vocabulary_size": len(names),
        "params": {
            "n": int(n),
            "min_share": float(min_share),
            "sample": int(sample),
            "max_similarity": float(max_similarity),
            "seed": int(seed),
        },
    }
    if added:
        log.info("map_negatives for %r: %s", qs.query, ", ".join(added))
    return out


class MapNegativesHeuristic(Heuristic):
    """Wrap ``base`` and add the names that the map's own items match best as negatives.

    Parameters
    ----------
    base
        The wrapped heuristic: an instance, a name or ``{name: ..., <param>: ...}``.
    n, min_share, vocabulary, sample, max_similarity, chunk, seed
        As in :func:`add_map_negatives`.

    Without a map in the context, the base heuristic's set is returned unchanged. The
    context's generic negatives are added before the mined ones, so the order of the
    negatives is the same as for the base heuristic alone.
    """

    name = "map-negatives"

    def __init__(
        self,
        base: Any = "none",
        n: int = 5,
        min_share: float = 0.01,
        vocabulary: str | Sequence[str] | None = None,
        sample: int = 20000,
        max_similarity: float = 0.8,
        chunk: int = 4096,
        seed: int = 0,
    ) -> None:
        from ._combine import build_heuristic

        self.base = build_heuristic(base, "map-negatives: base")
        self.n = n
        self.min_share = min_share
        self.vocabulary = vocabulary
        self.sample = sample
        self.max_similarity = max_similarity
        self.chunk = chunk
        self.seed = seed

    def params(self) -> dict[str, Any]:
        out = super().params()
        out["base"] = getattr(self.base, "name", type(self.base).__name__)
        return out

    def expand(self, query: str, context: ExpansionContext | None = None) -> QuerySet:
        qs = self.base.expand(query, context)
        if context is None or context.map is None or context.encoder is None:
            return qs
        qs = qs.with_negatives(context.negatives)
        return add_map_negatives(
            qs,
            context.map,
            context.encoder,
            cache=context.extra.get("cache"),
            n=self.n,
            min_share=self.min_share,
            vocabulary=self.vocabulary,
            sample=self.sample,
            max_similarity=self.max_similarity,
            chunk=self.chunk,
            seed=self.seed,
        )
