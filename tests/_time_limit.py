"""``time_limit(seconds)``: fail a block that runs too long instead of hanging the suite.

A guard against a read that blocks for ever (a FIFO, ``/dev/zero``, a YAML alias bomb),
not a timing assertion: the limits are tens of seconds, far above the work's own time.
"""

from __future__ import annotations

import contextlib
import signal


@contextlib.contextmanager
def time_limit(seconds: float):
    """Raise :class:`TimeoutError` in the block once ``seconds`` have passed (SIGALRM)."""

    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)
