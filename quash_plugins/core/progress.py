"""Progress reporting for long work: a rich bar on a terminal, log lines elsewhere."""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from collections.abc import Callable, Iterator

log = logging.getLogger("quash_plugins.progress")

#: Set by the CLI's --quiet; library users can set it too.
QUIET = False
#: Without a terminal, seconds between two progress lines: work that ends sooner logs
#: nothing (43 queries expanded in 0.0 s are not news), longer work a line every ~10 %.
MIN_INTERVAL = 2.0


@contextlib.contextmanager
def progress(total: int, description: str) -> Iterator[Callable[[int], None]]:
    """Yield ``advance(n)``; shows a bar on a TTY, or logs every ~10% otherwise (at most
    one line per :data:`MIN_INTERVAL` seconds, and none for work done sooner).

    ``advance(0)`` before any work is counted marks where the counted work starts: the
    logged times count from there, not from the ``with`` (a bar around
    :meth:`~quash_plugins.engine.Quash.query_many` counts map rows, and the text side
    before them is not classification time)."""
    if QUIET or total <= 0:
        yield lambda n: None
        return
    if sys.stderr.isatty():
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeRemainingColumn,
        )

        with Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeRemainingColumn(),
            transient=True,
        ) as bar:
            task = bar.add_task(description, total=total)
            yield lambda n: bar.advance(task, n)
        return
    t0 = time.perf_counter()
    state = {"done": 0, "next": max(1, total // 10), "t0": t0, "last": t0, "said": False}

    def advance(n: int) -> None:
        if n == 0 and state["done"] == 0:  # the counted work starts now
            state["t0"] = state["last"] = time.perf_counter()
            return
        state["done"] += n
        done = state["done"]
        if done < state["next"] and done < total:
            return
        state["next"] = done + max(1, total // 10)
        now = time.perf_counter()
        # the closing line once a line was logged, so a reported run is seen to end
        if now - state["last"] < MIN_INTERVAL and not (done >= total and state["said"]):
            return
        state["last"], state["said"] = now, True
        log.info(
            "%s: %d/%d (%.0f%%, %.1fs)",
            description,
            done,
            total,
            100.0 * done / total,
            now - state["t0"],
        )

    yield advance
