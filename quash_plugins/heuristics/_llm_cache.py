"""Where the ``llm`` heuristic keeps its query sets, and ``quash cache``'s view of them.

One JSON file per query set, named by a hash of its key (:func:`cache_file_name`), in
:func:`llm_cache_root`. The heuristic reads and writes single files
(:func:`read_query_set`, :func:`write_query_set`); ``quash cache info``
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
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..core.cache_dirs import cache_dir
from ..core.errors import HeuristicError, QuashError

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


def read_query_set(
    path: Path, key: dict[str, Any], warn: Callable[..., None]
) -> dict[str, Any] | None:
    """The record cached at ``path`` for ``key``, its ``synonyms`` and ``antonyms`` lists
    of strings (not yet cleaned); None when there is none, or another key's. A file that
    cannot serve (a link, unreadable, lists of other things) is None too, said through
    ``warn`` (the heuristic's ``log.warning``)."""
    if not path.exists() and not path.is_symlink():
        return None
    if path.is_symlink() or not path.is_file():
        warn("ignoring LLM cache entry %s: not a regular file", path)
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        warn("ignoring unreadable LLM cache file %s: %s", path, exc)
        return None
    if not isinstance(data, dict) or data.get("key") != key:
        return None
    lists = [data.get(side) for side in ("synonyms", "antonyms")]
    if not all(isinstance(v, list) and all(isinstance(w, str) for w in v) for v in lists):
        warn(
            "ignoring LLM cache file %s: 'synonyms' and 'antonyms' must be lists of strings",
            path,
        )
        return None
    return data


def write_query_set(path: Path, record: dict[str, Any], warn: Callable[..., None]) -> Path | None:
    """Write ``record`` (its ``key`` holds the query) to ``path`` atomically, in private
    folders; ``path``, or None, said through ``warn``, when it cannot be written."""
    from ..core.atomic import atomic_write_text
    from ..core.cache_dirs import make_private_dirs

    try:
        make_private_dirs(path.parent)
        atomic_write_text(path, json.dumps(record, indent=1, ensure_ascii=False))
    # unwritable, or a link or folder planted at the cache path (never followed)
    except (OSError, QuashError) as exc:
        warn("llm: query set for %r not cached: %s", record["key"]["query"], exc)
        return None
    return path


def offline_miss(key: dict[str, Any], where: Path | str) -> HeuristicError:
    """The error of an offline heuristic that has no query set for ``key`` in ``where``
    (its cache folder, or why there is none): what was looked for, and what to do."""
    sampled = f", temperature {key['temperature']}, seed {key['seed']}" if "seed" in key else ""
    return HeuristicError(
        f"Heuristic 'llm' is offline and has no cached query set for {key['query']!r} "
        f"(model {key['model']!r}, endpoint {key['endpoint']}, prompt "
        f"{key['prompt_version']}, n_synonyms {key['n_synonyms']}, n_antonyms "
        f"{key['n_antonyms']}{sampled}) in {where}. Run once with offline: false, or point "
        "cache_dir at the cache that has it."
    )


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
