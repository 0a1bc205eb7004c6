"""Where a recording goes: an ``.rrd`` file, a spawned viewer, a running one, or served.

Everything served listens on 127.0.0.1 unless the caller names another address
(``ViewerOptions.bind``). Rerun's own ``serve_web_viewer`` binds its HTTP server on
every interface (0.0.0.0) with no way to choose, so the web viewer is served by the
SDK's ``rerun`` executable, which takes ``--bind``; the gRPC server that holds the
recording runs in this process (``GrpcServerSink(bind_ip=...)``).

A viewer that cannot be reached is never waited for: with no display (Linux without
``DISPLAY``/``WAYLAND_DISPLAY``), a viewer that exits at start, or a ``--connect``
address where nothing listens, the logger says so in one line and carries on with the
other sinks.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit

from ..core.atomic import atomic_write
from ..core.errors import QuashError, UsageError
from ._machine import (
    _WILDCARDS,
    _bind_error,
    _connect_host,
    _listening,
    _parent_death_signal,
    _stop,
    _tail,
    _url_host,
    display_available,
    rerun_executable,
)
from ._rerun import RerunLogger, import_rerun

log = logging.getLogger(__name__)

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090
#: Address the servers listen on unless the user asks for another.
DEFAULT_BIND = "127.0.0.1"
#: Seconds to wait for a spawned viewer or the web viewer's HTTP server to listen.
START_TIMEOUT_S = 30.0
#: Seconds to wait for the recording's gRPC server (in this process) to listen.
GRPC_START_TIMEOUT_S = 10.0
#: Seconds :meth:`SinkRerunLogger.close` waits for streaming sinks to take the recording.
FLUSH_TIMEOUT_S = 120.0


@dataclass
class ViewerOptions:
    """Where a recording goes; several sinks can be on at once.

    Attributes
    ----------
    rrd
        Write a recording to this ``.rrd`` file (atomically).
    spawn
        Start the native viewer (the ``rerun`` executable) and stream to it.
    connect
        Stream to a running viewer at this URL (``rerun+http://host:9876/proxy``).
    serve_web
        Host a gRPC server and the web viewer and keep serving on close, until SIGINT
        (Ctrl-C) or SIGTERM.
    web_port, grpc_port
        Ports of the served web viewer and of its gRPC server.
    bind
        Address the served ports listen on: 127.0.0.1 unless you ask for another
        (``0.0.0.0`` serves every interface).
    quiet
        Say nothing of what was written or streamed (``wrote FILE.rrd``, ``streamed to
        ...``), as ``quash --quiet`` asks; warnings are still logged, and ``serve_web``
        still prints its URL (the one way to open what it serves).
    """

    rrd: str | Path | None = None
    spawn: bool = False
    connect: str | None = None
    serve_web: bool = False
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT
    bind: str = DEFAULT_BIND
    quiet: bool = False

    @property
    def requested(self) -> bool:
        """True when any sink is on."""
        return bool(self.rrd or self.spawn or self.connect or self.serve_web)


def check_bind(value: str, what: str = "--bind") -> str:
    """The IP address ``value`` for the servers to listen on; ``localhost`` is 127.0.0.1.

    Raises
    ------
    UsageError
        For a host name or a malformed address, naming ``what`` and the fix.
    """
    import ipaddress

    text = str(value).strip()
    if text.lower() == "localhost":
        return DEFAULT_BIND
    try:
        address = ipaddress.ip_address(text.strip("[]"))
    except ValueError:
        raise UsageError(
            f"{what} {value!r} is not an IP address. Give one such as 127.0.0.1 (this "
            "machine only, the default), 0.0.0.0 (every network interface) or an address of "
            "this machine; host names other than localhost are not accepted."
        ) from None
    if address.version != 4:
        raise UsageError(
            f"{what} {value!r} is an IPv6 address, which the viewer's servers do not take "
            "here. Give an IPv4 address: 127.0.0.1 (this machine only, the default) or "
            "0.0.0.0 (every network interface)."
        )
    return str(address)


def warn_if_exposed(bind: str, web_port: int, grpc_port: int) -> bool:
    """Warn that servers bound to ``bind`` are open to other machines, unless it is a
    loopback address (127.0.0.0/8); True when it warned."""
    import ipaddress

    if ipaddress.ip_address(bind).is_loopback:
        return False
    where = "every network interface" if bind in _WILDCARDS else f"the interface of {bind}"
    log.warning(
        "--bind %s: the web viewer (port %d) and the recording (port %d: the map and every "
        "result) are served on %s, to anyone who can reach this machine, with no password. "
        "Use --bind 127.0.0.1 (the default) and an SSH tunnel "
        "(ssh -L %d:127.0.0.1:%d -L %d:127.0.0.1:%d HOST) unless the network is yours.",
        bind,
        web_port,
        grpc_port,
        where,
        web_port,
        web_port,
        grpc_port,
        grpc_port,
    )
    return True


def check_distinct_ports(
    web: int | None, grpc: int | None, web_what: str = "--web-port", grpc_what: str = "--grpc-port"
) -> None:
    """Refuse one port for both servers of ``serve_web`` (None: the default port)."""
    web = DEFAULT_WEB_PORT if web is None else web
    grpc = DEFAULT_GRPC_PORT if grpc is None else grpc
    if web == grpc:
        raise UsageError(
            f"{web_what} and {grpc_what} are both {web}: the web viewer and its gRPC "
            "server need a port each. Give them different ports."
        )


def check_rrd_name(path: str | Path) -> None:
    """Refuse an ``--rrd`` whose name does not end in ``.rrd`` (:class:`UsageError`)."""
    if Path(path).suffix != ".rrd":
        raise UsageError(f"--rrd {path}: the file name must end in .rrd.")


def check_connect_url(url: str) -> None:
    """Refuse a ``--connect`` that is not a viewer URL (:class:`UsageError`)."""
    parts = urlsplit(url)
    if not parts.hostname or not parts.scheme.startswith("rerun"):
        raise UsageError(f"--connect {url}: expected a URL like rerun+http://127.0.0.1:9876/proxy.")


def check_port(value: Any, what: str = "port") -> int:
    """``value`` as a TCP port number in 1-65535, or a :class:`UsageError` naming ``what``."""
    try:
        port = int(value)
    except (TypeError, ValueError):
        port = None
    if port is None or not 1 <= port <= 65535:
        raise UsageError(f"{what} {value!r} is not a port number; give one from 1 to 65535.")
    return port


def web_viewer_url(web_port: int, grpc_uri: str, host: str = "127.0.0.1") -> str:
    """URL of the served web viewer, told to connect to ``grpc_uri``."""
    return f"http://{host}:{web_port}/?url={quote(grpc_uri, safe='')}"


class SinkRerunLogger(RerunLogger):
    """A :class:`RerunLogger` whose recording feeds the sinks of a :class:`ViewerOptions`.

    * ``rrd``: written to a temporary file beside the file and renamed over it in
      :meth:`close`, so the file is either the old one or the complete new recording.
    * ``spawn``: starts the native viewer (listening on 127.0.0.1) and streams to it;
      without a display, or when the viewer does not start, says so and carries on.
    * ``connect``: streams to a running viewer (``rerun+http://host:9876/proxy``); when
      nothing listens there, says so and carries on.
    * ``serve_web``: hosts a gRPC server and the web viewer on ``bind`` (127.0.0.1),
      prints the URL once, as soon as it is up, and keeps serving in :meth:`close`
      until SIGINT or SIGTERM (saying so, and pointing at that URL).
    """

    def __init__(self, sinks: ViewerOptions, app_id: str = "quash", **options: Any) -> None:
        rr = import_rerun()
        self.rrd_path = Path(sinks.rrd) if sinks.rrd else None
        self.serve_web = bool(sinks.serve_web)
        web, grpc = sinks.web_port, sinks.grpc_port
        self.web_port = check_port(DEFAULT_WEB_PORT if web is None else web, "--web-port")
        self.grpc_port = check_port(DEFAULT_GRPC_PORT if grpc is None else grpc, "--grpc-port")
        self.bind = check_bind(DEFAULT_BIND if sinks.bind is None else sinks.bind)
        if self.serve_web:
            check_distinct_ports(self.web_port, self.grpc_port, "web_port", "grpc_port")
            if sinks.spawn:
                self._check_spawn_beside_serve()
            warn_if_exposed(self.bind, self.web_port, self.grpc_port)
        self.url: str | None = None
        self.streaming: list[str] = []  # streaming sinks, for messages
        self.quiet = bool(sinks.quiet)  # no "wrote FILE" / "streamed to" line
        self._tmp: Path | None = None
        self._file = contextlib.ExitStack()
        self._web: subprocess.Popen | None = None
        self._closed = False
        recording = rr.RecordingStream(app_id)
        outputs: list[Any] = []
        if self.rrd_path is not None:
            check_rrd_name(self.rrd_path)
            self._tmp = self._file.enter_context(atomic_write(self.rrd_path, ".tmp"))
            self._finalizer = weakref.finalize(self, _remove, str(self._tmp))
            outputs.append(rr.FileSink(str(self._tmp)))
        try:
            if sinks.spawn:
                url = self._spawn()
                if url is not None:
                    outputs.append(rr.GrpcSink(url))
                    self.streaming.append(f"the Rerun viewer at {url}")
            if sinks.connect and self._reachable(sinks.connect):
                outputs.append(rr.GrpcSink(sinks.connect))
                self.streaming.append(f"the Rerun viewer at {sinks.connect}")
            server = None
            if self.serve_web:
                self._check_free(self.grpc_port, "--grpc-port")
                self._check_free(self.web_port, "--web-port")
                server = rr.GrpcServerSink(bind_ip=self.bind, port=self.grpc_port)
                outputs.append(server)
            recording.set_sinks(*outputs)
            if server is not None:
                self._wait_for_grpc_server()
                grpc_uri = f"rerun+http://{_url_host(self.bind)}:{self.grpc_port}/proxy"
                self._serve_web_viewer(grpc_uri)
                self.url = web_viewer_url(self.web_port, grpc_uri, _url_host(self.bind))
                print(f"Rerun web viewer: {self.url}", file=sys.stderr, flush=True)
        except BaseException:
            self._discard()
            raise
        super().__init__(recording, app_id, **options)

    def _check_spawn_beside_serve(self) -> None:
        """``--spawn`` with ``--serve-web``: the native viewer listens on
        127.0.0.1:9876, the served recording on ``bind:grpc_port``. When those are one
        address the server could not start once the viewer had, and the viewer just
        opened would be left behind: refused first, with the port to give instead.
        Without a display no viewer starts, so nothing collides."""
        same_port = self.grpc_port == DEFAULT_GRPC_PORT
        if not same_port or self.bind not in ("127.0.0.1", *_WILDCARDS):
            return
        if not display_available():
            return
        raise UsageError(
            f"--spawn and --serve-web both need port {DEFAULT_GRPC_PORT} on 127.0.0.1 (the "
            "native viewer listens there, and so would the served recording): serve on "
            f"another with --grpc-port {DEFAULT_GRPC_PORT + 1}, or drop one of the two."
        )

    # ------------------------------------------------------------------ sinks
    @staticmethod
    def _spawn() -> str | None:
        """Start the native viewer on 127.0.0.1; its URL, or None (said in one line)."""
        url = f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy"
        if not display_available():
            log.warning(
                "--spawn: no display (DISPLAY and WAYLAND_DISPLAY are unset), so no viewer "
                "is opened; carrying on (use --rrd FILE or --serve-web to see the result)."
            )
            return None
        if _listening("127.0.0.1", DEFAULT_GRPC_PORT):
            log.info("--spawn: a Rerun viewer already listens on 127.0.0.1:%d", DEFAULT_GRPC_PORT)
            return url
        exe = rerun_executable()
        if exe is None:
            log.warning(
                '--spawn: the rerun executable is not installed (pip install "quash-plugins[rerun]"); '
                "carrying on without a viewer."
            )
            return None
        cmd = [exe, "--port", str(DEFAULT_GRPC_PORT), "--bind", "127.0.0.1"]
        cmd += ["--memory-limit", "75%", "--expect-data-soon"]
        with tempfile.TemporaryFile() as err:  # the child keeps its own descriptor
            proc = subprocess.Popen(
                cmd,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
                env={**os.environ, "RERUN_APP_ONLY": "true"},
                start_new_session=True,  # the viewer stays open after this command ends
            )
            deadline = time.monotonic() + START_TIMEOUT_S
            while time.monotonic() < deadline:
                if proc.poll() is not None:
                    why = _tail(err) or f"exit code {proc.returncode}"
                    log.warning("--spawn: the Rerun viewer did not start (%s); carrying on.", why)
                    return None
                if _listening("127.0.0.1", DEFAULT_GRPC_PORT):
                    return url
                time.sleep(0.2)
        _stop(proc)
        log.warning(
            "--spawn: the Rerun viewer did not listen within %.0f s; carrying on.",
            START_TIMEOUT_S,
        )
        return None

    @staticmethod
    def _reachable(url: str) -> bool:
        """True when something listens at the host and port of a viewer URL."""
        check_connect_url(url)
        parts = urlsplit(url)
        try:
            port = parts.port
        except ValueError:
            port = None
        port = port or DEFAULT_GRPC_PORT
        if _listening(parts.hostname, port, timeout=2.0):
            return True
        log.warning(
            "--connect: nothing listens at %s:%d, so nothing is streamed there; carrying on.",
            parts.hostname,
            port,
        )
        return False

    def _check_free(self, port: int, option: str) -> None:
        """Refuse ``bind:port`` unless a server can listen there now: tried by binding
        that very address (0.0.0.0 conflicts with a listener on any of the machine's
        addresses, which connecting to 127.0.0.1 would not find)."""
        exc = _bind_error(self.bind, port)
        if exc is None:
            return
        if exc.errno == errno.EADDRNOTAVAIL:
            raise UsageError(
                f"--bind {self.bind} is not an address of this machine (none of its network "
                "interfaces has it), so nothing can listen there. Give --bind one of its own "
                "addresses: 127.0.0.1 (this machine only, the default), 0.0.0.0 (every "
                "network interface) or the address of one of its interfaces (ip -4 addr "
                "lists them)."
            )
        if exc.errno == errno.EADDRINUSE:
            where = (
                "another program listens on it, on this or another of the machine's addresses"
                if self.bind in _WILDCARDS
                else "another program listens on it"
            )
            raise QuashError(
                f"Port {port} on {self.bind} is in use ({where}); choose a free one with "
                f"{option} PORT."
            )
        if exc.errno in (errno.EACCES, errno.EPERM):
            raise QuashError(
                f"Port {port} on {self.bind} needs privileges this process does not have "
                f"(ports below 1024 usually do); choose another with {option} PORT."
            )
        raise QuashError(
            f"Cannot listen on {self.bind}:{port} ({exc.strerror or exc}); choose another "
            f"port with {option} PORT or another address with --bind."
        )

    def _wait_for_grpc_server(self) -> None:
        """Wait until the gRPC server listens: it reports a failure to listen only in a
        log line of its own thread, and the web viewer would point at nothing (or at
        another program that took the port since :meth:`_check_free`)."""
        host = _connect_host(self.bind)
        deadline = time.monotonic() + GRPC_START_TIMEOUT_S
        while not _listening(host, self.grpc_port):
            if time.monotonic() >= deadline:
                raise QuashError(
                    f"The recording's gRPC server did not listen on {self.bind}:"
                    f"{self.grpc_port} within {GRPC_START_TIMEOUT_S:.0f} s (see the error "
                    "above); choose a free port with --grpc-port PORT."
                )
            time.sleep(0.05)

    def _serve_web_viewer(self, grpc_uri: str) -> None:
        """Serve the web viewer's files over HTTP on ``bind:web_port`` (a ``rerun`` child)."""
        exe = rerun_executable()
        if exe is None:
            raise QuashError(
                '--serve-web needs the rerun executable of the SDK: pip install "quash-plugins[rerun]".'
            )
        cmd = [exe, "--serve-web", "--bind", self.bind, "--web-viewer-port", str(self.web_port)]
        host = _connect_host(self.bind)
        with tempfile.TemporaryFile() as err:  # the child keeps its own descriptor
            self._web = subprocess.Popen(
                [*cmd, grpc_uri],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
                env={**os.environ, "RERUN_APP_ONLY": "true"},
                preexec_fn=_parent_death_signal(),
            )
            self._web_finalizer = weakref.finalize(self, _stop, self._web)
            deadline = time.monotonic() + START_TIMEOUT_S
            while time.monotonic() < deadline:
                if self._web.poll() is not None:
                    why = _tail(err) or f"exit code {self._web.returncode}"
                    low = why.lower()
                    if "assign requested address" in low or "os error 99" in low:
                        fix = (
                            f"--bind {self.bind} is not an address of this machine: give "
                            "one of its own with --bind (127.0.0.1, the default, or 0.0.0.0)."
                        )
                    elif "in use" in low:
                        fix = "Choose a free port with --web-port."
                    else:
                        fix = "Choose another port with --web-port or another address with --bind."
                    raise QuashError(
                        f"Could not serve the web viewer on {self.bind}:{self.web_port} ({why}). "
                        + fix
                    )
                if _listening(host, self.web_port):
                    return
                time.sleep(0.2)
        raise QuashError(
            f"The web viewer did not listen on {self.bind}:{self.web_port} within "
            f"{START_TIMEOUT_S:.0f} s."
        )

    def _discard(self) -> None:
        """Remove the temporary ``.rrd`` and stop the web viewer (start-up failed)."""
        if self._tmp is not None:
            _remove(str(self._tmp))
            self._finalizer.detach()
        _stop(self._web)

    # ------------------------------------------------------------------ close
    def close(self) -> None:
        """Finish the ``.rrd`` (atomic rename); with ``serve_web``, serve until SIGINT
        (Ctrl-C) or SIGTERM, then stop the servers. Never waits on a viewer that is gone.
        """
        if self._closed:
            return
        self._closed = True
        rec = self.recording
        try:
            self.flush(timeout_s=FLUSH_TIMEOUT_S)
        except Exception as exc:  # a streaming sink that cannot take the data
            where = ", ".join(self.streaming) or "a streaming sink"
            log.warning("could not stream everything to %s (%s); carrying on.", where, exc)
        else:
            for where in [] if self.quiet else self.streaming:  # as "wrote FILE.rrd" does
                print(f"streamed to {where}", file=sys.stderr, flush=True)
        if self._tmp is not None:
            _finalize_files(rec)
            self._file.close()  # chmod to the umask, rename over the target
            self._finalizer.detach()
            if not self.quiet:
                print(f"wrote {self.rrd_path}", file=sys.stderr, flush=True)
        if self.serve_web:
            self._serve_until_stopped()
        with contextlib.suppress(Exception):
            rec.flush(timeout_sec=5.0)
        rec.disconnect()

    def _serve_until_stopped(self) -> None:
        # The URL was said once, when the viewer came up ("Rerun web viewer: URL", so it
        # could be opened while the command worked): this line says that everything is
        # logged and how to stop, and points there rather than printing the URL again.
        print(
            "Serving the Rerun web viewer (the URL above); press Ctrl-C to stop.",
            file=sys.stderr,
            flush=True,
        )
        stop = threading.Event()
        previous: dict[int, Any] = {}
        if threading.current_thread() is threading.main_thread():
            # Also when started in the background, where a shell ignores SIGINT.
            for sig in (signal.SIGINT, signal.SIGTERM):
                previous[sig] = signal.signal(sig, lambda *_: stop.set())
        try:
            while not stop.wait(0.5):
                if self._web is not None and self._web.poll() is not None:
                    log.warning(
                        "the web viewer server stopped (exit code %s).", self._web.returncode
                    )
                    break
        except KeyboardInterrupt:
            pass
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            _stop(self._web)
        print("stopped serving", file=sys.stderr, flush=True)


def _remove(path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def _finalize_files(rec: Any) -> None:
    """Write the footer of the recording's file sinks now; streaming sinks stay up.

    ``with rec: pass`` does the same but first flushes without a time limit, which
    would wait forever on a viewer that went away.
    """
    try:
        import rerun_bindings

        rerun_bindings.finalize_deferred_sinks(recording=rec.to_native())
    except (ImportError, AttributeError, TypeError):  # pragma: no cover - other SDKs
        with rec:
            pass


def open_viewer(sinks: ViewerOptions, app_id: str = "quash", **options: Any) -> Any:
    """A :class:`SinkRerunLogger` for ``sinks``, or None when no sink is on.

    Call ``close()`` on the result when everything is logged.
    """
    if not sinks.requested:
        return None
    return SinkRerunLogger(sinks, app_id=app_id, **options)
