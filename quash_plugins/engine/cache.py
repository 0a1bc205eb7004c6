"""On-disk text-embedding cache, keyed by encoder fingerprint and exact string.

Layout::

    <directory>/v1/<fingerprint>/<shard>.npz       texts (n,) str, embeddings (n, D) float32
    <directory>/v1/<fingerprint>/<shard>.npz.lock  filelock for writers

Each string goes to one of :data:`SHARDS` shard files of its encoder's fingerprint
(by a hash of the string). Why files and not sqlite:

- **Concurrent processes.** Writers take the shard's file lock, re-read the shard, merge
  and replace it with an atomic rename; readers take no lock and always see a whole
  file (the old or the new one). This holds on any file system where ``rename`` is atomic,
  including network file systems where sqlite's locking is unreliable.
- **Corruption stays local.** A damaged shard (truncated write, disk error, edited by
  hand) fails its checksum, is reported with a logging warning and removed; its strings
  are simply encoded again and the shard is rebuilt. A query never fails because of it.
- **Bounded.** After a write the cache evicts least-recently-used shard files (a read
  refreshes a shard's mtime) until the total is under ``max_bytes``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import stat
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core.atomic import atomic_write
from ..core.cache_dirs import cache_dir

log = logging.getLogger(__name__)

#: Bump when the on-disk layout changes; old versions are ignored (and removed by clear).
FORMAT = "v1"
#: Texts longer than this are embedded but not cached: a shard stores its texts as one
#: fixed-width array, so one 120,000-character query widened every entry of its shard
#: and the eviction that followed emptied most of the cache.
MAX_CACHED_CHARS = 512
#: Shard files per encoder fingerprint.
SHARDS = 16
#: Default size bound (bytes); overridable by ``QUASH_CACHE_MAX_MB`` or ``max_bytes``.
DEFAULT_MAX_BYTES = 512 * 2**20
#: Seconds a writer waits for a shard lock before giving up on storing (never fatal).
LOCK_TIMEOUT = 30.0


def default_cache_dir() -> Path:
    """``$QUASH_CACHE_DIR/text-embeddings``, else ``<user cache dir>/quash-plugins/text-embeddings``."""
    return cache_dir("text-embeddings")


def _default_max_bytes() -> int:
    env = os.environ.get("QUASH_CACHE_MAX_MB")
    if env:
        try:
            return int(float(env) * 2**20)
        except ValueError:
            log.warning("QUASH_CACHE_MAX_MB=%r is not a number; using the default", env)
    return DEFAULT_MAX_BYTES


def _safe_name(fingerprint: str) -> str:
    safe = re.sub(r"[^A-Za-z0-9._-]", "_", fingerprint)[:80]
    if safe != fingerprint or safe.startswith("."):
        safe = f"{safe.lstrip('.')}-{hashlib.sha256(fingerprint.encode()).hexdigest()[:12]}"
    return safe


def _shard_of(text: str) -> str:
    return f"{hashlib.sha256(text.encode('utf-8', 'surrogatepass')).digest()[0] % SHARDS:02d}"


def _checksum(fingerprint: str, texts: np.ndarray, emb: np.ndarray) -> str:
    h = hashlib.sha256(fingerprint.encode())
    h.update("\x00".join(texts.tolist()).encode("utf-8", "surrogatepass"))
    h.update(np.ascontiguousarray(emb, dtype=np.float32).tobytes())
    return h.hexdigest()


class CorruptCacheFile(Exception):
    """A shard file that cannot be read or fails its checksum."""


class TextEmbeddingCache:
    """Text embeddings on disk, shared by every process of the user.

    Parameters
    ----------
    directory
        Cache directory; default :func:`default_cache_dir` (env ``QUASH_CACHE_DIR``).
    max_bytes
        Size bound; least-recently-used shards are evicted beyond it. Default 512 MiB
        (env ``QUASH_CACHE_MAX_MB``).

    Attributes
    ----------
    hits, misses
        Strings served from / not found in the cache by this object.
    corrupt
        Paths of corrupt shard files found (and removed) by this object.

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> cache = TextEmbeddingCache(tempfile.mkdtemp())
    >>> cache.store("enc-1", {"chair": np.array([0.6, 0.8], np.float32)})
    >>> cache.lookup("enc-1", ["chair", "sofa"])["chair"].tolist()
    [0.6000000238418579, 0.800000011920929]
    """

    def __init__(self, directory: str | Path | None = None, max_bytes: int | None = None) -> None:
        self.directory = Path(directory).expanduser() if directory else default_cache_dir()
        self.max_bytes = int(max_bytes) if max_bytes is not None else _default_max_bytes()
        self.hits = 0
        self.misses = 0
        self.corrupt: list[Path] = []
        # Shards read and checked, by path, with the file identity they were read at:
        # a lookup re-reads a shard only when another process has replaced it.
        self._memo: dict[Path, tuple[tuple, dict[str, np.ndarray]]] = {}

    def __repr__(self) -> str:
        return f"TextEmbeddingCache({str(self.directory)!r}, max_bytes={self.max_bytes})"

    @property
    def root(self) -> Path:
        return self.directory / FORMAT

    def _dir(self, fingerprint: str) -> Path:
        return self.root / _safe_name(fingerprint)

    # ------------------------------------------------------------------ reading
    def _read(self, path: Path, fingerprint: str) -> dict[str, np.ndarray]:
        """Read one shard; raise :class:`CorruptCacheFile` when it is damaged.

        A symbolic link, folder or device planted at a shard's path is never read (a pipe
        would block): it counts as damage, and a link is removed, never followed.
        """
        try:
            st = path.lstat()
        except FileNotFoundError:
            return {}
        except OSError as exc:
            raise CorruptCacheFile(f"cannot inspect it ({exc.strerror})") from None
        if not stat.S_ISREG(st.st_mode):
            raise CorruptCacheFile("not a regular file")
        stamp = (fingerprint, st.st_ino, st.st_size, st.st_mtime_ns)
        memo = self._memo.get(path)
        if memo is not None and memo[0] == stamp:
            return memo[1]  # unchanged since it was read and checked
        try:
            with np.load(path, allow_pickle=False) as z:
                texts = np.asarray(z["texts"])
                emb = np.asarray(z["embeddings"], dtype=np.float32)
                meta = json.loads(str(z["meta"]))
        except FileNotFoundError:
            return {}
        except Exception as exc:  # noqa: BLE001 - any decoding failure means corrupt
            raise CorruptCacheFile(f"unreadable ({type(exc).__name__}: {exc})") from None
        if meta.get("fingerprint") != fingerprint:
            raise CorruptCacheFile("it belongs to another encoder fingerprint")
        if emb.ndim != 2 or texts.ndim != 1 or len(texts) != len(emb):
            raise CorruptCacheFile(f"shapes texts {texts.shape} and embeddings {emb.shape}")
        if meta.get("sha256") != _checksum(fingerprint, texts, emb):
            raise CorruptCacheFile("checksum mismatch")
        table = {str(t): emb[i] for i, t in enumerate(texts.tolist())}
        if len(self._memo) >= 4 * SHARDS:
            self._memo.pop(next(iter(self._memo)))
        self._memo[path] = (stamp, table)
        return table

    def _restamp(self, path: Path, fingerprint: str) -> None:
        """After touching a shard's time (LRU), keep its memo valid."""
        memo = self._memo.get(path)
        if memo is None:
            return
        try:
            st = path.lstat()
        except OSError:
            self._memo.pop(path, None)
            return
        if memo[0][:3] == (fingerprint, st.st_ino, st.st_size):
            self._memo[path] = ((fingerprint, st.st_ino, st.st_size, st.st_mtime_ns), memo[1])

    def _report_corrupt(self, path: Path, why: Any) -> None:
        log.warning(
            "text-embedding cache file %s is corrupt (%s); removing it, its strings will be "
            "encoded again and the shard rebuilt",
            path,
            why,
        )
        self.corrupt.append(path)
        with contextlib.suppress(OSError):
            path.unlink()

    def lookup(self, fingerprint: str, texts: Sequence[str]) -> dict[str, np.ndarray]:
        """Cached embeddings ``{text: (D,) float32}`` for the strings of ``texts`` it has."""
        folder = self._dir(fingerprint)
        wanted: dict[str, set[str]] = {}
        for t in texts:
            wanted.setdefault(_shard_of(t), set()).add(t)
        found: dict[str, np.ndarray] = {}
        if folder.is_dir():
            for shard, strings in wanted.items():
                path = folder / f"{shard}.npz"
                try:
                    table = self._read(path, fingerprint)
                except CorruptCacheFile as exc:
                    self._report_corrupt(path, exc)
                    continue
                except OSError as exc:
                    log.warning("cannot read text-embedding cache file %s: %s", path, exc)
                    continue
                hit = {t: table[t].copy() for t in strings if t in table}
                if hit:
                    found.update(hit)
                    with contextlib.suppress(OSError):
                        os.utime(path)  # LRU: a read refreshes the shard
                        self._restamp(path, fingerprint)
        n_unique = len(set(texts))
        self.hits += len(found)
        self.misses += n_unique - len(found)
        return found

    # ------------------------------------------------------------------ writing
    def store(self, fingerprint: str, embeddings: dict[str, np.ndarray]) -> None:
        """Add ``{text: (D,) float32}``; failures are logged, never raised."""
        if not embeddings:
            return
        try:
            self._store(fingerprint, embeddings)
        except Exception as exc:  # noqa: BLE001 - a cache must never break a query
            log.warning("could not write the text-embedding cache in %s: %s", self.directory, exc)
            return
        try:
            self.evict()
        except Exception as exc:  # noqa: BLE001
            log.warning("text-embedding cache eviction failed in %s: %s", self.directory, exc)

    def _store(self, fingerprint: str, embeddings: dict[str, np.ndarray]) -> None:
        from filelock import FileLock, Timeout

        from ..core.cache_dirs import make_private_dirs

        folder = make_private_dirs(self._dir(fingerprint))
        by_shard: dict[str, dict[str, np.ndarray]] = {}
        for t, v in embeddings.items():
            if len(t) > MAX_CACHED_CHARS:  # a shard stores its texts at the longest's width
                continue
            by_shard.setdefault(_shard_of(t), {})[t] = np.asarray(v, dtype=np.float32).ravel()
        for shard, new in by_shard.items():
            path = folder / f"{shard}.npz"
            try:
                with FileLock(str(path) + ".lock", timeout=LOCK_TIMEOUT):
                    try:
                        table = dict(self._read(path, fingerprint))  # never the memo itself
                    except CorruptCacheFile as exc:
                        self._report_corrupt(path, exc)
                        table = {}
                    dims = {v.shape[0] for v in new.values()} | {v.shape[0] for v in table.values()}
                    if len(dims) > 1:  # same fingerprint, new dimension: start the shard over
                        table = {}
                    table.update(new)
                    texts = np.asarray(list(table), dtype=str)
                    emb = np.stack(list(table.values())).astype(np.float32)
                    meta = {
                        "fingerprint": fingerprint,
                        "sha256": _checksum(fingerprint, texts, emb),
                        "written": time.time(),
                    }
                    with atomic_write(path, suffix=".npz") as tmp:
                        np.savez(
                            tmp, texts=texts, embeddings=emb, meta=np.asarray(json.dumps(meta))
                        )
            except Timeout:
                log.warning(
                    "text-embedding cache shard %s is locked; not caching %d strings",
                    path,
                    len(new),
                )

    # ------------------------------------------------------------------ housekeeping
    def _files(self) -> list[tuple[Path, os.stat_result]]:
        out = []
        if not self.root.is_dir():
            return out
        for sub in self.root.iterdir():
            if not sub.is_dir():
                continue
            for p in sub.glob("*.npz"):
                with contextlib.suppress(OSError):
                    out.append((p, p.stat()))
        return out

    def size(self) -> int:
        """Bytes used by shard files."""
        return sum(st.st_size for _, st in self._files())

    def evict(self, max_bytes: int | None = None) -> int:
        """Remove least-recently-used shards until the total is under the bound.

        Returns the number of bytes removed.
        """
        limit = self.max_bytes if max_bytes is None else int(max_bytes)
        files = self._files()
        total = sum(st.st_size for _, st in files)
        if total <= limit:
            return 0
        removed = 0
        target = int(limit * 0.9)
        for path, st in sorted(files, key=lambda f: f[1].st_mtime_ns):
            if total - removed <= target:
                break
            with contextlib.suppress(OSError):
                path.unlink()
                removed += st.st_size
        log.info("text-embedding cache: evicted %d bytes (bound %d)", removed, limit)
        return removed

    def info(self) -> dict[str, Any]:
        """Location, size, bound, and per-fingerprint entry counts."""
        encoders: dict[str, dict[str, Any]] = {}
        for path, st in self._files():
            fp = path.parent.name
            rec = encoders.setdefault(
                fp, {"fingerprint": fp, "entries": 0, "bytes": 0, "files": 0, "last_used": 0.0}
            )
            rec["bytes"] += st.st_size
            rec["files"] += 1
            rec["last_used"] = max(rec["last_used"], st.st_mtime)
            try:
                with np.load(path, allow_pickle=False) as z:
                    meta = json.loads(str(z["meta"]))
                    rec["fingerprint"] = meta.get("fingerprint", fp)
                    rec["entries"] += len(z["texts"])
            except Exception:  # noqa: BLE001 - info never fails on a bad file
                rec["corrupt_files"] = rec.get("corrupt_files", 0) + 1
        recs = sorted(encoders.values(), key=lambda r: -r["last_used"])
        return {
            "directory": str(self.directory),
            "bytes": sum(r["bytes"] for r in recs),
            "max_bytes": self.max_bytes,
            "entries": sum(r["entries"] for r in recs),
            "files": sum(r["files"] for r in recs),
            "encoders": recs,
        }

    def fingerprints(self) -> list[str]:
        """The fingerprints that have shards in this cache (their folder names)."""
        if not self.root.is_dir():
            return []
        return sorted(d.name for d in self.root.iterdir() if d.is_dir() and any(d.glob("*.npz")))

    def clear(self, fingerprint: str | None = None) -> int:
        """Delete every cached embedding (or one fingerprint's). Returns bytes freed.

        Only the cache's own files are deleted (``v<N>/<fingerprint>/*.npz`` shards and
        their ``.lock`` files), then the folders they leave empty: a folder given as
        ``--dir`` that holds anything else (a ``v1/notes.txt``) keeps it.
        """
        if fingerprint is not None:
            target = self._dir(fingerprint)
            return _remove_shards(target) if target.is_dir() else 0
        freed = 0
        if self.directory.is_dir():
            for sub in self.directory.iterdir():
                if sub.is_dir() and not sub.is_symlink() and re.fullmatch(r"v\d+", sub.name):
                    for fp_dir in sub.iterdir():
                        if fp_dir.is_dir() and not fp_dir.is_symlink():
                            freed += _remove_shards(fp_dir)
                    with contextlib.suppress(OSError):
                        sub.rmdir()  # only when nothing else is left in it
        return freed


def _remove_shards(folder: Path) -> int:
    """Delete the cache's shard files (``*.npz``, ``*.npz.lock``) in ``folder``, then the
    folder if that left it empty; every other file stays. Returns bytes freed."""
    freed = 0
    for p in folder.iterdir():
        if (
            p.is_file()
            and not p.is_symlink()
            and (p.suffix == ".npz" or p.name.endswith(".npz.lock"))
        ):
            with contextlib.suppress(OSError):
                size = p.stat().st_size
                p.unlink()
                freed += size
    left = [p.name for p in folder.iterdir()]
    if left:
        log.warning(
            "%s: kept %d file(s) that are not the cache's own (%s)",
            folder,
            len(left),
            ", ".join(sorted(left)[:3]) + (", ..." if len(left) > 3 else ""),
        )
    else:
        with contextlib.suppress(OSError):
            folder.rmdir()
    return freed


def open_cache(setting: Any) -> Any:
    """Turn a config's ``cache`` setting into a cache object, or None.

    ``True`` opens the default on-disk :class:`TextEmbeddingCache`; ``False``/``None``
    turn caching off; a cache object is returned as it is. ``QUASH_NO_CACHE=1`` in the
    environment turns every cache off (``0``, ``false``, ``no``, ``off`` or empty: not).
    """
    no_cache = os.environ.get("QUASH_NO_CACHE", "").strip().lower()
    if setting is None or setting is False or no_cache not in ("", "0", "false", "no", "off"):
        return None
    if setting is True:
        return TextEmbeddingCache()
    return setting
