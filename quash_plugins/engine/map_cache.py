"""The maps a :class:`~quash_plugins.engine.pipeline.Quash` has read, reused while their
source is unchanged.

A file or folder is keyed by its resolved path, adapter and options and versioned by
the modification time and size of it and of every file the adapter read for the map
(``source["inputs"]``: VLMaps' ``vlmap/vlmaps.h5df`` inside the folder given, the labels
beside a map), so a map that a mapping process keeps rewriting is read again, whether
it was given as its file or as its folder; a live object (a ``VLMap``) by its id, adapter and options, versioned by the
identity and shape of every array it holds and the value of every number or string
(its ``cs``, ``gs``), with a reference to it so that a new object at a freed id is not
taken for it. Least recently used maps go first.
"""

from __future__ import annotations

import weakref
from pathlib import Path
from typing import Any

from ..core.types import LatentMap


class MapCache:
    """Read maps by source: ``lookup`` before reading, ``store`` after."""

    def __init__(self) -> None:
        # key -> (version, reference to a live source or None, map), oldest first
        self._maps: dict[Any, tuple[Any, Any, LatentMap]] = {}

    def lookup(self, source: Any, adapter: str, opts: dict[str, Any]) -> tuple[Any, Any]:
        """``(map or None, token)``: the kept map when ``source`` is unchanged; pass the
        token to :meth:`store` with the map read otherwise."""
        key, version, ref = _map_key(source, adapter, opts)
        if key is not None:
            hit = self._maps.pop(key, None)
            # a live source must be the same object, not a new one at a freed id
            if (
                hit is not None
                and hit[0] == _with_inputs(version, ref, hit[2])
                and (hit[1] is None or hit[1]() is source)
            ):
                self._maps[key] = hit  # the most recently used goes last
                return hit[2], None
            # an outdated map is dropped here, before the source is read again, so that
            # the old map's arrays are not held beside the new one's
            del hit
        return None, (key, version, ref)

    def store(self, token: Any, lmap: LatentMap, keep: int) -> None:
        """Keep ``lmap`` under ``token`` (from :meth:`lookup`), at most ``keep`` maps."""
        key, version, ref = token
        if key is None:  # a source that cannot be told unchanged is read every time
            return
        self._maps[key] = (_with_inputs(version, ref, lmap), ref, lmap)
        while len(self._maps) > max(int(keep), 0):
            del self._maps[next(iter(self._maps))]

    def clear(self) -> None:
        self._maps.clear()


def _with_inputs(version: Any, ref: Any, lmap: LatentMap) -> Any:
    """A file source's ``version`` with the modification time and size of every file
    or folder the map was read from (its ``source["inputs"]``), and of the files in such
    a folder (a folder input stands for them: ConceptFusion's ``pointclouds/``, whose
    ``pc_*.h5`` gradslam rewrites in place, which leaves the folder's own time as it
    was); a live source's as is."""
    if ref is not None:
        return version
    from ..core.types import source_inputs

    stats = []
    for path in source_inputs(lmap.source):
        p = Path(path)
        try:
            st = p.stat()
            stats.append((path, st.st_mtime_ns, st.st_size))
            if p.is_dir():
                stats += [_stat(f) for f in sorted(p.iterdir()) if f.is_file()]
        except (OSError, RuntimeError):  # gone (a taxonomy that was never there)
            stats.append((path, None, None))
    return version, tuple(stats)


def _stat(path: Path) -> tuple[str, Any, Any]:
    try:
        st = path.stat()
        return str(path), st.st_mtime_ns, st.st_size
    except OSError:  # removed between the listing and the look
        return str(path), None, None


def _map_key(source: Any, adapter: str, opts: dict[str, Any]) -> tuple[Any, Any, Any]:
    """``(key, version, ref)`` of a map source: a file's modification time and size, or
    a live object's arrays, with a reference to the object (None for a file). ``key`` is
    None when the source cannot be told unchanged (it is then read every time)."""
    options = repr(sorted(opts.items()))
    if isinstance(source, (str, Path)):
        p = Path(source).expanduser()
        try:
            st = p.stat()
            return (str(p.resolve()), adapter, options), (st.st_mtime_ns, st.st_size), None
        except (OSError, RuntimeError):  # missing, unreadable, a symbolic-link loop
            return None, None, None
    state = getattr(source, "__dict__", None)
    if not isinstance(state, dict):
        return None, None, None
    try:
        ref: Any = weakref.ref(source)
    except TypeError:  # e.g. a SimpleNamespace: held (the kept map holds its arrays anyway)
        ref = _Held(source)
    return (id(source), adapter, options), _arrays_of(state), ref


class _Held:
    """A strong reference with the call interface of a weak one."""

    __slots__ = ("obj",)

    def __init__(self, obj: Any) -> None:
        self.obj = obj

    def __call__(self) -> Any:
        return self.obj


def _arrays_of(state: dict[str, Any]) -> tuple[Any, ...]:
    """The identity and shape of every array-like attribute of a live object, and the
    value of every number or string one (a cell size set anew: ``vlmap.cs = 0.1``)."""
    return tuple(
        (k, id(v), tuple(getattr(v, "shape", ()))) if hasattr(v, "shape") else (k, v)
        for k, v in state.items()
        if hasattr(v, "shape") or isinstance(v, (int, float, str))
    )
