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

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_EXPORTS = {
    "Encoder": "interfaces",
    "Heuristic": "interfaces",
    "Classifier": "interfaces",
    "MapAdapter": "interfaces",
    "ExpansionContext": "interfaces",
    "LatentMap": "types",
    "QuerySet": "types",
    "QueryResult": "types",
    "Instance": "types",
    "FrameInfo": "types",
    "DEFAULT_NEGATIVES": "types",
    "Quash": "pipeline",
    "QuashConfig": "config",
    "QuashError": "errors",
    "registry": None,
}

__all__ = [
    "DEFAULT_NEGATIVES",
    "Classifier",
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
    "registry",
]

if TYPE_CHECKING:  # pragma: no cover
    from . import registry
    from .config import QuashConfig
    from .errors import QuashError
    from .interfaces import Classifier, Encoder, ExpansionContext, Heuristic, MapAdapter
    from .pipeline import Quash
    from .types import DEFAULT_NEGATIVES, FrameInfo, Instance, LatentMap, QueryResult, QuerySet


def __getattr__(name: str) -> Any:
    import importlib

    if name not in _EXPORTS:
        raise AttributeError(f"module 'quash_plugins' has no attribute {name!r}")
    module = _EXPORTS[name]
    if module is None:
        return importlib.import_module(f".{name}", __name__)
    return getattr(importlib.import_module(f".{module}", __name__), name)


def __dir__() -> list[str]:
    return sorted([*globals(), *_EXPORTS])
