"""Where the ``llm`` heuristic keeps its query sets, and ``quash cache``'s view of them.

One JSON file per query set, named by a hash of its key (:func:`cache_file_name`), in
:func:`llm_cache_root`. The heuristic reads and writes single files; ``quash cache info``
and ``quash cache clear --llm`` list and delete them (:func:`llm_cache_info`,
:func:`clear_llm_cache`), touching only files named like a set, never through a link.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
from pathlib import Path
from typing import Any

from ..core.cache_dirs import cache_dir

log = logging.getLogger(__name__)

#: The name of one cached query set: a hash of its key, ``.json``.
CACHE_FILE_RE = re.compile(r"^[0-9a-f]{32}\.json$")


def default_cache_dir() -> Path:
    """``$QUASH_CACHE_DIR/llm``, else the user cache dir of quash-plugins, ``/llm``."""
    return cache_dir("llm")


def llm_cache_root(directory: str | Path | None = None) -> Path:
    """The folder of the cached query sets: ``directory`` (a config's ``cache_dir``, or
    ``quash cache --dir``), else :func:`default_cache_dir`."""
    return Path(directory).expanduser().absolute() if directory else default_cache_dir()


def cache_file_name(key: dict[str, Any]) -> str:
    """The file name of the query set whose cache key is ``key`` (matches
    :data:`CACHE_FILE_RE`)."""
    blob = json.dumps(key, sort_keys=True).encode()
    return f"{hashlib.sha256(blob).hexdigest()[:32]}.json"


def _cache_files(directory: Path) -> list[Path]:
    """The query-set files of ``directory``: regular files named like one, never through a
    symbolic link (a linked folder or file is left alone)."""
    if directory.is_symlink() or not directory.is_dir():
        return []
    out = []
    with os.scandir(directory) as entries:
        for entry in entries:
            if CACHE_FILE_RE.match(entry.name) and entry.is_file(follow_symlinks=False):
                out.append(Path(entry.path))
    return sorted(out)


def llm_cache_info(directory: str | Path | None = None) -> dict[str, Any]:
    """Where the LLM query sets are cached, how many, their size, and the sets per model
    and endpoint (``quash cache info``). ``directory``: see :func:`llm_cache_root`."""
    root = llm_cache_root(directory)
    groups: dict[tuple[str, str], dict[str, Any]] = {}
    total = 0
    files = _cache_files(root)
    for path in files:
        with contextlib.suppress(OSError):
            total += path.stat().st_size
        try:
            key = json.loads(path.read_text(encoding="utf-8")).get("key") or {}
            model, endpoint = str(key.get("model", "?")), str(key.get("endpoint", "?"))
        except (OSError, ValueError, AttributeError):
            model, endpoint = "(unreadable)", ""
        rec = groups.setdefault(
            (model, endpoint), {"model": model, "endpoint": endpoint, "sets": 0}
        )
        rec["sets"] += 1
    return {
        "directory": str(root),
        "sets": len(files),
        "bytes": total,
        "models": sorted(groups.values(), key=lambda r: (-r["sets"], r["model"])),
    }


def clear_llm_cache(directory: str | Path | None = None) -> tuple[int, int]:
    """Delete the cached LLM query sets of ``directory`` (see :func:`llm_cache_root`):
    only files named like one, never through a symbolic link. Returns (sets, bytes)."""
    n = freed = 0
    for path in _cache_files(llm_cache_root(directory)):
        try:
            size = path.stat().st_size
            path.unlink()
        except OSError as exc:
            log.warning("llm: could not delete %s: %s", path, exc)
            continue
        n, freed = n + 1, freed + size
    return n, freed
