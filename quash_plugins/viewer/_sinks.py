"""Where a recording goes: an ``.rrd`` file, a spawned viewer, a running one, or served."""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
import tempfile
import time
import weakref
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

from ..core.errors import QuashError, UsageError
from ._rerun import RerunLogger, import_rerun

log = logging.getLogger(__name__)

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090


def _remove(path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


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
        Host a gRPC server and the web viewer on 127.0.0.1 and keep serving on close.
    web_port, grpc_port
        Ports of the served web viewer and of its gRPC server.
    """

    rrd: str | Path | None = None
    spawn: bool = False
    connect: str | None = None
    serve_web: bool = False
    web_port: int = DEFAULT_WEB_PORT
    grpc_port: int = DEFAULT_GRPC_PORT

    @property
    def requested(self) -> bool:
        """True when any sink is on."""
        return bool(self.rrd or self.spawn or self.connect or self.serve_web)


def is_rrd(path: str | Path) -> bool:
    """True when ``path`` is a Rerun recording (its magic bytes): a previous ``--rrd``
    output that may be replaced without ``--force``."""
    try:
        with open(path, "rb") as f:
            return f.read(3) == b"RRF"
    except OSError:
        return False


def web_viewer_url(web_port: int, grpc_uri: str, host: str = "127.0.0.1") -> str:
    """URL of the served web viewer, told to connect to ``grpc_uri``."""
    return f"http://{host}:{web_port}/?url={quote(grpc_uri, safe='')}"


class SinkRerunLogger(RerunLogger):
    """A :class:`RerunLogger` whose recording feeds the sinks of a :class:`ViewerOptions`.

    * ``rrd``: written to a temporary file beside the file and renamed over it in
      :meth:`close`, so the file is either the old one or the complete new recording.
    * ``spawn``: starts the native viewer (the ``rerun`` executable) and streams to it.
    * ``connect``: streams to a running viewer (``rerun+http://host:9876/proxy``).
    * ``serve_web``: hosts a gRPC server and the web viewer on 127.0.0.1, prints the
      URL, and keeps serving in :meth:`close` until Ctrl-C.
    """

    def __init__(self, sinks: ViewerOptions, app_id: str = "quash", **options: Any) -> None:
        rr = import_rerun()
        self.rrd_path = Path(sinks.rrd) if sinks.rrd else None
        self.serve_web = bool(sinks.serve_web)
        self.web_port = int(sinks.web_port or DEFAULT_WEB_PORT)
        self.grpc_port = int(sinks.grpc_port or DEFAULT_GRPC_PORT)
        self.url: str | None = None
        self._tmp: str | None = None
        self._closed = False
        recording = rr.RecordingStream(app_id)
        outputs: list[Any] = []
        if self.rrd_path is not None:
            if self.rrd_path.suffix != ".rrd":
                raise UsageError(f"--rrd {self.rrd_path}: the file name must end in .rrd.")
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
            fd, self._tmp = tempfile.mkstemp(
                prefix=f".{self.rrd_path.name}.", suffix=".tmp", dir=self.rrd_path.parent
            )
            os.close(fd)
            self._finalizer = weakref.finalize(self, _remove, self._tmp)
            outputs.append(rr.FileSink(self._tmp))
        try:
            if sinks.spawn:
                outputs.append(self._spawn(rr))
            if sinks.connect:
                outputs.append(rr.GrpcSink(sinks.connect))
            server = None
            if self.serve_web:
                server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=self.grpc_port)
                outputs.append(server)
            recording.set_sinks(*outputs)
            if server is not None:
                rr.serve_web_viewer(
                    web_port=self.web_port, open_browser=False, connect_to=server.uri
                )
                self.url = web_viewer_url(self.web_port, server.uri)
                print(f"Rerun web viewer: {self.url}", file=sys.stderr, flush=True)
        except QuashError:
            self._discard()
            raise
        except Exception as exc:
            self._discard()
            raise QuashError(
                f"Could not start the Rerun output ({exc}). Check --connect, or choose free "
                "ports with --grpc-port / --web-port."
            ) from None
        super().__init__(recording, app_id, **options)

    @staticmethod
    def _spawn(rr: Any) -> Any:
        exe = shutil.which("rerun") or str(Path(sys.executable).with_name("rerun"))
        if not Path(exe).exists():
            raise QuashError(
                'The native Rerun viewer (rerun) is not installed: pip install "quash-plugins[rerun]", '
                "or use --rrd / --serve-web."
            )
        rr.spawn(port=DEFAULT_GRPC_PORT, connect=False, executable_path=exe)
        return rr.GrpcSink(f"rerun+http://127.0.0.1:{DEFAULT_GRPC_PORT}/proxy")

    def _discard(self) -> None:
        if self._tmp is not None:
            _remove(self._tmp)

    def close(self) -> None:
        """Finish the ``.rrd`` (atomic rename), then serve until Ctrl-C with ``--serve-web``."""
        if self._closed:
            return
        self._closed = True
        super().close()
        rec = self.recording
        if self._tmp is not None:
            # Leaving the recording's context flushes and finalises file sinks (footer
            # written); streaming sinks stay up. The thread-local recording is restored.
            with rec:
                pass
            os.replace(self._tmp, self.rrd_path)
            self._finalizer.detach()
            print(f"wrote {self.rrd_path}", file=sys.stderr, flush=True)
        if self.serve_web:
            print(
                f"Serving the Rerun web viewer at {self.url}\nPress Ctrl-C to stop.",
                file=sys.stderr,
                flush=True,
            )
            try:
                while True:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                print("stopped serving", file=sys.stderr, flush=True)
        rec.flush()
        rec.disconnect()


def open_viewer(sinks: ViewerOptions, app_id: str = "quash", **options: Any) -> Any:
    """A :class:`SinkRerunLogger` for ``sinks``, or None when no sink is on.

    Call ``close()`` on the result when everything is logged.
    """
    if not sinks.requested:
        return None
    return SinkRerunLogger(sinks, app_id=app_id, **options)
