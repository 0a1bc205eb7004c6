"""Temporary names beside an output, and the removal of those a killed process left.

Every temporary name :mod:`quash_plugins.core.atomic` makes beside an output says that
quash made it, on which machine and in which process (``.NAME.quash-tmp-HOST-PID-RANDOM``):
a process killed outright (SIGKILL, a power cut) cannot remove it, so the next write of
the same output removes those whose process is gone (:func:`remove_stale`). Public
through :mod:`quash_plugins.core.atomic`.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import re
import secrets
import shutil
import socket
import stat
from pathlib import Path

log = logging.getLogger("quash_plugins.core.atomic")


def _host() -> str:
    """Six hexadecimal digits naming this machine: a process number means something
    only on the machine that ran it (an output folder may be shared over the network)."""
    return hashlib.sha256(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:6]


def _tag(kind: str) -> str:
    """``quash-KIND-HOST-PID-RANDOM``: what a temporary name beside an output carries, so
    that :func:`remove_stale` knows quash made it and whether its process still runs."""
    return f"quash-{kind}-{_host()}-{os.getpid()}-{secrets.token_hex(4)}"


#: A temporary name of :func:`atomic_write` (``tmp`` and a suffix: a file) or of
#: :func:`atomic_dir` (``tmp`` without a suffix: the new folder; ``old``: the folder it
#: replaces, moved aside), or one :func:`remove_stale` is removing (``del``).
_STALE = re.compile(
    r"quash-(?P<kind>tmp|old|del)-(?P<host>[0-9a-f]{6})-(?P<pid>[0-9]{1,10})-[0-9a-f]{8}"
    r"(?P<suffix>\.[A-Za-z0-9]{1,8})?"
)


def _process_gone(pid: int) -> bool:
    """True only when no process ``pid`` runs on this machine (a zombie still counts)."""
    if os.name == "nt" or pid <= 0 or pid == os.getpid():
        return False  # on Windows os.kill(pid, 0) would send Ctrl-C: never guess there
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except OSError:  # EPERM: it runs, as another user
        return False
    return False


def remove_stale(path: str | Path) -> list[Path]:
    """Remove the temporary files and folders beside ``path`` that a quash process killed
    outright (SIGKILL, out of memory, a power cut) left there; return them.

    Only names that quash made for ``path`` (``.NAME.quash-tmp-HOST-PID-RANDOM[.SUFFIX]``,
    ``.NAME.quash-old-...``), made on this machine by a process that no longer runs, are
    touched; never a symbolic link, nor a file where quash makes a folder or the other
    way round, nor anything else. A previous folder output moved aside (``old``) whose
    replacement never arrived (``path`` is missing) is moved back to ``path`` instead.
    Each is logged. Errors are ignored: the write goes on, and a later one tries again.
    """
    path = Path(path).expanduser()
    prefix = f".{path.name}."
    try:
        with os.scandir(path.parent if str(path.parent) else ".") as it:
            names = [e.name for e in it if e.name.startswith(prefix)]
    except OSError:
        return []
    here, removed = _host(), []
    for name in names:
        m = _STALE.fullmatch(name, len(prefix))
        if not m or m["host"] != here or not _process_gone(int(m["pid"])):
            continue
        stale = path.parent / name
        try:
            st = stale.lstat()
        except OSError:
            continue
        is_dir, is_file = stat.S_ISDIR(st.st_mode), stat.S_ISREG(st.st_mode)
        kind, suffix = m["kind"], m["suffix"]
        if not (
            (kind == "tmp" and (is_file if suffix else is_dir))
            or (kind == "old" and is_dir and not suffix)
            or (kind == "del" and (is_file or is_dir))
        ):
            continue
        what = f"left by quash process {m['pid']}, which was stopped before it finished"
        if kind == "old" and not os.path.lexists(path):
            try:
                os.rename(stale, path)  # the previous output, put back
            except OSError:
                continue
            log.info("put %s back: a write %s had moved it aside to %s", path, what, name)
            continue
        # A name of its own first, so that two processes never remove the same thing.
        mine = path.parent / f"{prefix}{_tag('del')}{suffix or ''}"
        try:
            os.rename(stale, mine)
        except OSError:
            continue
        if is_dir:
            shutil.rmtree(mine, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                mine.unlink()
        log.info("removed %s, %s", stale, what)
        removed.append(stale)
    return removed
