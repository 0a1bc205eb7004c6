"""Where quash-plugins keeps its caches: one root for every cache, one folder each.

``$QUASH_CACHE_DIR/<part>`` when the variable is set, else ``<part>`` in the user cache
directory of quash-plugins (``~/.cache/quash-plugins`` on Linux). The text-embedding
cache, the LLM query sets and the demo's scenes each have their folder under it.

Every folder a cache creates is private (mode 0700, whatever the umask): on a shared
machine other users can neither read the cached queries nor plant embeddings or query
sets in them. A folder that exists already keeps its mode.

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


def make_private_dirs(path: str | Path) -> Path:
    """Create ``path`` and its missing parents with mode 0700; existing ones are left as
    they are. Returns ``path``.

    ``os.makedirs(mode=...)`` gives the mode to the last folder only, and the umask can
    widen none of these: each missing folder is made on its own with 0700.
    """
    path = Path(path)
    missing = []
    p = path
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    for folder in reversed(missing):
        try:
            os.mkdir(folder, 0o700)
        except FileExistsError:  # made meanwhile by another process
            continue
    return path


__all__ = ["cache_dir", "make_private_dirs"]
