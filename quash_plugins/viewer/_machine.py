"""This machine, as the viewer's sinks see it: the SDK's ``rerun`` executable, whether
a display is there, which addresses and ports are free or listening, and the child
processes (a spawned or serving viewer) started and stopped."""

from __future__ import annotations

import contextlib
import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

#: Addresses that bind every interface.
_WILDCARDS = ("0.0.0.0", "::", "")


def rerun_executable() -> str | None:
    """The ``rerun`` executable of the installed SDK, else one on ``PATH``; None if none."""
    name = "rerun.exe" if sys.platform == "win32" else "rerun"
    spec = importlib.util.find_spec("rerun_cli")
    candidates = []
    if spec is not None and spec.origin:
        candidates.append(Path(spec.origin).parent / name)
    candidates.append(Path(sys.executable).with_name(name))
    found = shutil.which("rerun")
    if found:
        candidates.append(Path(found))
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return str(path)
    return None


def display_available(environ: Any = None) -> bool:
    """False on Linux (and other X11/Wayland systems) when no display is set.

    macOS and Windows always have one for a desktop session.
    """
    env = os.environ if environ is None else environ
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(env.get("DISPLAY") or env.get("WAYLAND_DISPLAY"))


def _listening(host: str, port: int, timeout: float = 0.5) -> bool:
    """True when something accepts TCP connections on ``host:port``."""
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True
    except OSError:
        return False


def _bind_error(host: str, port: int) -> OSError | None:
    """The error a TCP server binding ``host:port`` now would get; None when it can.

    The socket is only bound, never listened on, and closed at once. On POSIX it sets
    ``SO_REUSEADDR`` as the servers do, so connections of an earlier server that linger
    in TIME_WAIT do not count as a busy port, while a listener does.
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        if os.name == "posix":
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((host, port))
        except OSError as exc:
            return exc
    return None


def _connect_host(bind: str) -> str:
    """The address a client on this machine uses for a server bound to ``bind``."""
    return "127.0.0.1" if bind in _WILDCARDS else bind


def _url_host(bind: str) -> str:
    """The host to print in URLs for a server bound to ``bind``."""
    if bind in _WILDCARDS:
        return socket.gethostname()
    return f"[{bind}]" if ":" in bind else bind


def _parent_death_signal() -> Any:
    """Linux: a ``preexec_fn`` that has the child get SIGTERM when this process dies, even
    by SIGKILL, so a served web viewer never outlives its command. None elsewhere.

    ``prctl`` is looked up here, in the parent; the child only calls it (one system call
    between fork and exec).
    """
    if not sys.platform.startswith("linux"):
        return None
    try:
        import ctypes

        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):  # pragma: no cover - unusual libc
        return None
    sig = int(signal.SIGTERM)

    def preexec() -> None:  # pragma: no cover - runs in the child
        prctl(1, sig)  # PR_SET_PDEATHSIG

    return preexec


def _tail(stream: Any) -> str:
    """The last non-empty line of a child's captured stderr, without ANSI colours."""
    import re

    try:
        stream.seek(0)
        text = stream.read().decode("utf-8", "replace")
    except (OSError, ValueError):
        return ""
    lines = [re.sub(r"\x1b\[[0-9;]*m", "", ln).strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines:
        return ""
    last = lines[-1]
    if len(last) > 100 and ": " in last:  # "Error: ... at /src/x.rs:788: Failed to open..."
        last = last.rsplit(": ", 1)[1]
    return last[:200]


def _stop(proc: subprocess.Popen | None, timeout: float = 5.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        proc.terminate()
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            proc.kill()
        proc.wait(timeout=timeout)
