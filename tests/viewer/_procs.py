"""Helpers of the tests that run the CLI and a browser as child processes."""

from __future__ import annotations

import re
import socket
import subprocess
import threading
import time


def free_port() -> int:
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Lines:
    """A pipe's lines, read in a thread so the child never blocks on a full pipe."""

    def __init__(self, pipe) -> None:
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._pump, args=(pipe,), daemon=True)
        self._t.start()

    def _pump(self, pipe) -> None:
        for line in iter(pipe.readline, ""):
            self.lines.append(line)

    def wait_for(self, pattern: str, timeout: float, proc: subprocess.Popen) -> re.Match:
        """The first match of the regular expression ``pattern`` in a line; fails when
        ``proc`` exits or ``timeout`` seconds pass first."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                m = re.search(pattern, line)
                if m:
                    return m
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"no line matching {pattern!r}; got:\n{''.join(self.lines)}")

    def text(self) -> str:
        self._t.join(timeout=10)
        return "".join(self.lines)
