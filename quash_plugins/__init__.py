"""quash-plugins: QuASH (Query Augmentation using Semantic Heuristics) for the maps
robots already build.

A query is expanded into positives and negatives by a :class:`Heuristic`, embedded by
the map's own :class:`Encoder`, used to train a :class:`Classifier`, and the
classifier labels every item of a map read by a :class:`MapAdapter`.

Examples
--------
>>> from quash_plugins import Quash, Encoder, Heuristic, Classifier, MapAdapter
>>> from quash_plugins import registry
>>> "npz" in registry.available("adapters")
True
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .core.optional import lazy_exports

__version__ = "0.1.0"

_EXPORTS = {
    "Encoder": ".core.interfaces",
    "Heuristic": ".core.interfaces",
    "Classifier": ".core.interfaces",
    "MapAdapter": ".core.interfaces",
    "ExpansionContext": ".core.interfaces",
    "StackableClassifier": ".core.interfaces",
    "CosineClassifier": ".core.interfaces",
    "LatentMap": ".core.types",
    "QuerySet": ".core.types",
    "QueryResult": ".core.types",
    "Instance": ".core.types",
    "FrameInfo": ".core.types",
    "DEFAULT_NEGATIVES": ".core.types",
    "Quash": ".engine.pipeline",
    "QuashConfig": ".core.config",
    "QuashError": ".core.errors",
    "registry": ".core.registry",
}

__all__ = [
    "DEFAULT_NEGATIVES",
    "Classifier",
    "CosineClassifier",
    "Encoder",
    "ExpansionContext",
    "FrameInfo",
    "Heuristic",
    "Instance",
    "LatentMap",
    "MapAdapter",
    "Quash",
    "QuashConfig",
    "QuashError",
    "QueryResult",
    "QuerySet",
    "StackableClassifier",
    "registry",
]

if TYPE_CHECKING:  # pragma: no cover
    from .core import registry
    from .core.config import QuashConfig
    from .core.errors import QuashError
    from .core.interfaces import (
        Classifier,
        CosineClassifier,
        Encoder,
        ExpansionContext,
        Heuristic,
        MapAdapter,
        StackableClassifier,
    )
    from .core.types import DEFAULT_NEGATIVES, FrameInfo, Instance, LatentMap, QueryResult, QuerySet
    from .engine.pipeline import Quash


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
