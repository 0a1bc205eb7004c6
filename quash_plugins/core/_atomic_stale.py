"""Temporary names beside an output, and the removal of those a killed process left.

Every temporary name :mod:`quash_plugins.core.atomic` makes beside an output says that
quash made it, on which machine and in which process (``.NAME.quash-tmp-HOST-PID-RANDOM``),
and the writer holds an exclusive lock (``flock``) on a lock file named from the same tag
(``.NAME.quash-lck-HOST-PID-RANDOM``) for the whole write (:func:`hold_lock`). A process
killed outright (SIGKILL, a power cut) cannot remove its temporaries, but the kernel
releases its lock: the next write of the same output removes those whose lock it can
take and whose process is gone (:func:`remove_stale`). The lock, not the process number,
is what tells a running writer in another PID namespace (a container, ``unshare --pid``)
or on another machine of the same name sharing the folder. Public through
:mod:`quash_plugins.core.atomic`.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import logging
import os
import re
import secrets
import shutil
import socket
import stat
from collections.abc import Iterator
from pathlib import Path

from .errors import UsageError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: nothing is locked, nothing removed
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger("quash_plugins.core.atomic")


def _host() -> str:
    """Six hexadecimal digits naming this machine: a process number means something
    only on the machine that ran it (an output folder may be shared over the network)."""
    return hashlib.sha256(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:6]


def _tag(kind: str) -> str:
    """``quash-KIND-HOST-PID-RANDOM``: what a temporary name beside an output carries, so
    that :func:`remove_stale` knows quash made it and whether its process still runs."""
    return f"quash-{kind}-{_host()}-{os.getpid()}-{secrets.token_hex(4)}"


def _retag(tag: str, kind: str) -> str:
    """The same tag for another kind of temporary of the same write."""
    return f"quash-{kind}-{tag.split('-', 2)[2]}"


#: A temporary name of :func:`atomic_write` (``tmp`` and a suffix: a file) or of
#: :func:`atomic_dir` (``tmp`` without a suffix: the new folder; ``old``: the folder it
#: replaces, moved aside), one :func:`remove_stale` is removing (``del``), or the lock
#: file that its writer holds while they exist (``lck``).
_STALE = re.compile(
    r"quash-(?P<kind>tmp|old|del|lck)-(?P<id>(?P<host>[0-9a-f]{6})-(?P<pid>[0-9]{1,10})-"
    r"[0-9a-f]{8})(?P<suffix>\.[A-Za-z0-9]{1,8})?"
)

#: The lock files this process holds: closed in a child made by fork, so that only the
#: writer itself keeps its temporaries alive (subprocesses never get them: O_CLOEXEC).
_HELD: set[int] = set()
if hasattr(os, "register_at_fork"):

    def _close_held_in_child() -> None:
        for fd in list(_HELD):
            with contextlib.suppress(OSError):
                os.close(fd)
        _HELD.clear()

    os.register_at_fork(after_in_child=_close_held_in_child)


def _process_gone(pid: int) -> bool:
    """True only when no process ``pid`` runs in this PID namespace (a zombie counts as
    running). Not enough alone: a writer in another namespace is not seen here."""
    if os.name == "nt" or pid <= 0 or pid == os.getpid():
        return False  # on Windows os.kill(pid, 0) would send Ctrl-C: never guess there
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # EPERM: it runs, as another user
        return False
    return False


@contextlib.contextmanager
def hold_lock(path: Path, tag: str) -> Iterator[None]:
    """Create the lock file of the temporaries named with ``tag`` beside ``path`` and
    hold an exclusive ``flock`` on it until the block ends (success, error, Ctrl-C),
    then remove it. Raises :class:`UsageError` naming the output when it cannot be
    created. Where the file system cannot lock, nothing is held (:func:`remove_stale`
    cannot lock there either, so it removes nothing)."""
    if fcntl is None:  # pragma: no cover - Windows
        yield
        return
    lock = path.parent / f".{path.name}.{_retag(tag, 'lck')}"
    fd = -1
    try:
        flags = os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC | os.O_NOFOLLOW
        try:
            fd = os.open(lock, flags, 0o600)
        except OSError as exc:
            raise UsageError(
                f"Cannot write {path}: {exc.strerror} ({path.parent}). Choose a writable folder."
            ) from None
        except BaseException:  # Ctrl-C once made: the name is ours (O_EXCL, random)
            with contextlib.suppress(OSError):
                os.unlink(lock)
            raise
        os.set_inheritable(fd, False)
        _HELD.add(fd)
        with contextlib.suppress(OSError):  # not supported here: remove_stale cannot lock either
            fcntl.flock(fd, fcntl.LOCK_EX)  # blocks only while a remove_stale looks at it
        yield
    finally:
        if fd >= 0:
            with contextlib.suppress(OSError):
                os.unlink(lock)  # unlinked while still held, then released
            _HELD.discard(fd)
            os.close(fd)


def _take_lock(lock: Path) -> int | None:
    """An fd of ``lock`` holding its exclusive lock when its writer is gone (the kernel
    released it), else None: its writer holds it (EWOULDBLOCK), or whether it does cannot
    be told (locking unsupported, no permission, the file was replaced)."""
    if fcntl is None:  # pragma: no cover - Windows
        return None
    try:  # read-write: NFS locks a file only when it is open for writing
        fd = os.open(lock, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        if os.path.samestat(os.fstat(fd), os.lstat(lock)):
            return fd  # still the file of that name: not removed by another cleaner
    except OSError as exc:
        if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.ENOENT):
            log.debug("cannot tell whether %s is held (%s): left as it is", lock, exc)
    os.close(fd)
    return None


def _kind_fits(kind: str, suffix: str | None, st: os.stat_result) -> bool:
    """Quash makes a file (``tmp`` with a suffix, ``lck``) or a folder there, never a link."""
    is_dir, is_file = stat.S_ISDIR(st.st_mode), stat.S_ISREG(st.st_mode)
    return (
        (kind == "tmp" and (is_file if suffix else is_dir))
        or (kind == "old" and is_dir and not suffix)
        or (kind == "del" and (is_file or is_dir))
        or (kind == "lck" and is_file and not suffix)
    )


def remove_stale(path: str | Path) -> list[Path]:
    """Remove the temporary files and folders beside ``path`` that a quash process killed
    outright (SIGKILL, out of memory, a power cut) left there; return them.

    Only names that quash made for ``path`` (``.NAME.quash-tmp-HOST-PID-RANDOM[.SUFFIX]``,
    ``.NAME.quash-old-...``) are touched, and only when their lock file
    (``.NAME.quash-lck-...``) exists and its lock can be taken (the writer is gone, in
    whatever PID namespace or machine it ran) AND they were made on this machine by a
    process that no longer runs; never a symbolic link, nor a file where quash makes a
    folder or the other way round, nor anything else. A previous folder output moved
    aside (``old``) whose replacement never arrived (``path`` is missing) is moved back
    to ``path`` instead. Each is logged. Errors are ignored: the write goes on, and a
    later one tries again.
    """
    path = Path(path).expanduser()
    parent = path.parent if str(path.parent) else Path(".")
    prefix = f".{path.name}."
    try:
        with os.scandir(parent) as it:
            names = [e.name for e in it if e.name.startswith(prefix)]
    except OSError:
        return []
    here, groups = _host(), {}
    for name in names:
        m = _STALE.fullmatch(name, len(prefix))
        if m and m["host"] == here:
            groups.setdefault(m["id"], []).append((name, m))
    removed: list[Path] = []
    for members in groups.values():
        locks = [name for name, m in members if m["kind"] == "lck" and not m["suffix"]]
        if not locks:  # no lock file: made before quash locked, or being made: never guess
            continue
        fd = _take_lock(parent / locks[0])
        if fd is None:
            continue
        try:
            if not _process_gone(int(members[0][1]["pid"])):
                continue
            done = [_remove_one(path, parent / n, m, removed) for n, m in members if n not in locks]
            if all(done):
                with contextlib.suppress(OSError):
                    os.unlink(parent / locks[0])
        finally:
            os.close(fd)
    return removed


def _remove_one(path: Path, stale: Path, m: re.Match[str], removed: list[Path]) -> bool:
    """Remove (or put back) one temporary of a writer known to be gone; False when left."""
    try:
        st = stale.lstat()
    except OSError:
        return True  # already gone
    kind, suffix = m["kind"], m["suffix"]
    if not _kind_fits(kind, suffix, st):
        return False
    what = f"left by quash process {m['pid']}, which was stopped before it finished"
    if kind == "old" and not os.path.lexists(path):
        try:
            os.rename(stale, path)  # the previous output, put back
        except OSError:
            return False
        log.info("put %s back: a write %s had moved it aside to %s", path, what, stale.name)
        return True
    # A name of its own first (locked while it is removed), so that two processes never
    # remove the same thing and a cleaner killed meanwhile leaves something removable.
    tag = _tag("del")
    try:
        with hold_lock(path, tag):
            mine = stale.parent / f".{path.name}.{tag}{suffix or ''}"
            os.rename(stale, mine)
            if stat.S_ISDIR(st.st_mode):
                shutil.rmtree(mine, ignore_errors=True)
            else:
                mine.unlink()
    except (OSError, UsageError):
        return False
    log.info("removed %s, %s", stale, what)
    removed.append(stale)
    return True
