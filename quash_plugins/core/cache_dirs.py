"""Where quash-plugins keeps its caches: one root for every cache, one folder each.

``$QUASH_CACHE_DIR/<part>`` when the variable is set, else ``<part>`` in the user cache
directory of quash-plugins (``~/.cache/quash-plugins`` on Linux). The text-embedding
cache, the LLM query sets and the demo's scenes each have their folder under it.

>>> cache_dir("llm").name, cache_dir("llm").parent == cache_dir("demo").parent
('llm', True)
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir(part: str) -> Path:
    """The folder of the cache ``part`` (``"text-embeddings"``, ``"llm"``, ``"demo"``)."""
    root = os.environ.get("QUASH_CACHE_DIR")
    if root:
        return Path(root).expanduser() / part
    import platformdirs

    return Path(platformdirs.user_cache_dir("quash-plugins")) / part


__all__ = ["cache_dir"]
