"""Recordings for the command line: ``--rrd``, ``--spawn``, ``--connect``, ``--serve-web``."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import shutil
import sys
import tempfile
import time
import weakref
from pathlib import Path
from typing import Any
from urllib.parse import quote

from ..errors import QuashError, UsageError
from ._rerun import RerunLogger, import_rerun

log = logging.getLogger(__name__)

DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090


def _remove(path: str) -> None:
    with contextlib.suppress(FileNotFoundError):
        os.unlink(path)


def web_viewer_url(web_port: int, grpc_uri: str, host: str = "127.0.0.1") -> str:
    """URL of the served web viewer, told to connect to ``grpc_uri``."""
    return f"http://{host}:{web_port}/?url={quote(grpc_uri, safe='')}"


class CliRerunLogger(RerunLogger):
    """A :class:`RerunLogger` whose recording feeds the sinks chosen on the command line.

    * ``--rrd FILE``: written to a temporary file beside ``FILE`` and renamed over it in
      :meth:`close`, so ``FILE`` is either the old file or the complete new recording.
    * ``--spawn``: starts the native viewer (the ``rerun`` executable) and streams to it.
    * ``--connect URL``: streams to a running viewer (``rerun+http://host:9876/proxy``).
    * ``--serve-web``: hosts a gRPC server and the web viewer on 127.0.0.1, prints the
      URL, and keeps serving in :meth:`close` until Ctrl-C.
    """

    def __init__(self, args: argparse.Namespace, app_id: str = "quash", **options: Any) -> None:
        rr = import_rerun()
        self.rrd_path = Path(args.rrd) if getattr(args, "rrd", None) else None
        self.serve_web = bool(getattr(args, "serve_web", False))
        self.web_port = int(getattr(args, "web_port", None) or DEFAULT_WEB_PORT)
        self.grpc_port = int(getattr(args, "grpc_port", None) or DEFAULT_GRPC_PORT)
        self.url: str | None = None
        self._tmp: str | None = None
        self._closed = False
        recording = rr.RecordingStream(app_id)
        sinks: list[Any] = []
        if self.rrd_path is not None:
            if self.rrd_path.suffix != ".rrd":
                raise UsageError(f"--rrd {self.rrd_path}: the file name must end in .rrd.")
            self.rrd_path.parent.mkdir(parents=True, exist_ok=True)
            fd, self._tmp = tempfile.mkstemp(
                prefix=f".{self.rrd_path.name}.", suffix=".tmp", dir=self.rrd_path.parent
            )
            os.close(fd)
            self._finalizer = weakref.finalize(self, _remove, self._tmp)
            sinks.append(rr.FileSink(self._tmp))
        try:
            if getattr(args, "spawn", False):
                sinks.append(self._spawn(rr))
            if getattr(args, "connect", None):
                sinks.append(rr.GrpcSink(args.connect))
            server = None
            if self.serve_web:
                server = rr.GrpcServerSink(bind_ip="127.0.0.1", port=self.grpc_port)
                sinks.append(server)
            recording.set_sinks(*sinks)
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


def viewer_from_cli(args: argparse.Namespace, app_id: str = "quash", **options: Any) -> RerunLogger:
    """A :class:`RerunLogger` for the viewer options parsed from the command line.

    ``args`` carries ``rrd``, ``spawn``, ``connect``, ``serve_web`` and optionally
    ``web_port`` and ``grpc_port`` (see ``quash_plugins.cli._viewer_opts``). Call
    ``close()`` on the result when everything is logged.
    """
    return CliRerunLogger(args, app_id=app_id, **options)
