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


@contextlib.contextmanager
def progress(total: int, description: str) -> Iterator[Callable[[int], None]]:
    """Yield ``advance(n)``; shows a bar on a TTY, or logs every ~10% otherwise."""
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
    state = {"done": 0, "next": max(1, total // 10), "t0": time.perf_counter()}

    def advance(n: int) -> None:
        state["done"] += n
        if state["done"] >= state["next"] or state["done"] >= total:
            log.info(
                "%s: %d/%d (%.0f%%, %.1fs)",
                description,
                state["done"],
                total,
                100.0 * state["done"] / total,
                time.perf_counter() - state["t0"],
            )
            state["next"] = state["done"] + max(1, total // 10)

    yield advance
