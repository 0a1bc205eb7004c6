"""Built-in heuristics: how a query becomes positives and negatives.

Each heuristic is registered as an entry point (``quash_plugins.heuristics``) and
imported on first use; importing this package imports none of them.
"""

from __future__ import annotations

from ..core.optional import lazy_exports

_EXPORTS = {
    "AutoHeuristic": "._auto",
    "NoneHeuristic": "._basic",
    "StaticHeuristic": "._basic",
    "LLMHeuristic": "._llm",
    "LLM_DEFAULT_BASE_URL": "._llm",
    "llm_cache_info": "._llm_cache",
    "clear_llm_cache": "._llm_cache",
    "llm_cache_root": "._llm_cache",
    "TaxonomyHeuristic": "._taxonomy",
    "LabelListHeuristic": "._taxonomy",
    "normalise_name": "._taxonomy",
    "taxonomy_beside": "._taxonomy",
    "taxonomy_path_beside": "._taxonomy",
    "LexiconHeuristic": "._lexicon",
    "AdjectivesHeuristic": "._adjectives",
    "TemplatesHeuristic": "._templates",
    "VocabularyHeuristic": "._vocabulary",
    "CombineHeuristic": "._combine",
    "MapNegativesHeuristic": "._mined",
    "add_map_negatives": "._mined",
}

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
