"""The text side of :meth:`Quash.query_many <quash_plugins.engine.pipeline.Quash.query_many>`.

:func:`prepare` is the body of ``Quash._prepare``: expand each query (once), embed the
strings of all query sets in one encoder call, fit one classifier per query; each query's
timings so far. The pipeline decides whether the steps show progress
(``PROGRESS_QUERIES``, read there).
"""

from __future__ import annotations

import time
from typing import Any

from sklearn.base import clone

from ..core.text import encode_texts
from ..core.types import LatentMap
from .answer import Pending
from .training import CallCache


def prepare(
    quash: Any, lmap: LatentMap, texts: list[str], t_read: float, many: bool
) -> list[Pending]:
    """The text side of every query of ``texts`` for ``quash``; ``many``: show progress."""
    from ..core.progress import progress

    timings = [{"read": t_read / len(texts)} for _ in texts]
    call_cache = CallCache(quash.cache)
    t = time.perf_counter()
    if len(texts) > 1:  # one encoder call for every query, for heuristics that embed it
        encode_texts(quash.encoder, list(dict.fromkeys(texts)), call_cache)
    t_queries = (time.perf_counter() - t) / len(texts)
    querysets = []
    with progress(len(texts) if many else 0, f"expanding {len(texts)} queries") as advance:
        for text, tm in zip(texts, timings):
            t = time.perf_counter()
            querysets.append(quash.expand(text, lmap, cache=call_cache))
            tm["expand"] = time.perf_counter() - t
            advance(1)
    t = time.perf_counter()
    with progress(len(texts) if many else 0, f"encoding {len(texts)} query sets") as advance:
        sets = quash.training_sets(querysets, progress=advance, cache=call_cache)
    t_encode = (time.perf_counter() - t) / len(texts) + t_queries
    pending = []
    with progress(len(texts) if many else 0, f"fitting {len(texts)} classifiers") as advance:
        for qs, (X, y, _), tm in zip(querysets, sets, timings):
            tm["encode"] = t_encode
            t = time.perf_counter()
            clf = clone(quash.classifier).fit(X, y)
            tm["fit"] = time.perf_counter() - t
            pending.append(Pending(qs, X, y, clf, tm))
            advance(1)
    return pending
