"""Built-in heuristics: how a query becomes positives and negatives.

Each heuristic is registered as an entry point (``quash_plugins.heuristics``) and
imported on first use; importing this package imports none of them.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "AutoHeuristic": "._auto",
    "NoneHeuristic": "._basic",
    "StaticHeuristic": "._basic",
    "LLMHeuristic": "._llm",
    "TaxonomyHeuristic": "._taxonomy",
    "LabelListHeuristic": "._taxonomy",
    "normalise_name": "._taxonomy",
    "taxonomy_beside": "._taxonomy",
    "LexiconHeuristic": "._lexicon",
    "AdjectivesHeuristic": "._adjectives",
    "TemplatesHeuristic": "._templates",
    "VocabularyHeuristic": "._vocabulary",
    "CombineHeuristic": "._combine",
    "MapNegativesHeuristic": "._mined",
    "add_map_negatives": "._mined",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
