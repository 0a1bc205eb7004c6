"""The results of :meth:`Quash.query_many <quash_plugins.engine.pipeline.Quash.query_many>`.

:func:`query_results` turns the answered queries (each an
:class:`~quash_plugins.engine.answer.Pending`, the map side done) into
:class:`~quash_plugins.core.types.QueryResult` objects: their instances grouped when the
pipeline groups them, their total time, the words of their classifier and the map's
source.
"""

from __future__ import annotations

import time
from typing import Any

from ..core.types import LatentMap, QueryResult
from .answer import Pending, classifier_words


def query_results(quash: Any, lmap: LatentMap, pending: list[Pending]) -> list[QueryResult]:
    """One :class:`QueryResult` for each of ``pending``, in order."""
    results = []
    for p in pending:
        instances = []
        if quash.instances is not None:
            from .instances import find_instances

            t = time.perf_counter()
            instances = find_instances(lmap, p.mask, p.display, **quash.instances)
            p.timings["instances"] = time.perf_counter() - t
        p.timings["total"] = sum(p.timings.values())
        results.append(
            QueryResult(
                queryset=p.queryset,
                mask=p.mask,
                scores=p.raw,
                display_scores=p.display,
                threshold=quash.threshold,
                instances=instances,
                timings=p.timings,
                classifier=classifier_words(p),
                config_name=quash.name,
                map_source=dict(lmap.source),
                rejected=p.rejected,
            )
        )
    return results
