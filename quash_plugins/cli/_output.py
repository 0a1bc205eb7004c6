"""Console output of the subcommands: logging, JSON and rich tables."""

from __future__ import annotations

import json
import logging
import sys
from typing import Any

log = logging.getLogger("quash_plugins.cli")


def setup_logging(verbose: int, quiet: bool) -> None:
    """Route ``quash_plugins`` logging to stderr through rich, credentials redacted."""
    from rich.console import Console
    from rich.logging import RichHandler

    from ..core import progress as _progress
    from ..core.redact import RedactingFilter

    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    _progress.QUIET = quiet
    handler = RichHandler(
        console=Console(stderr=True),
        show_time=False,
        show_path=verbose > 1,
        markup=False,
        rich_tracebacks=False,
    )
    handler.addFilter(RedactingFilter())
    handler.addFilter(_EscapeControls())
    root = logging.getLogger("quash_plugins")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


class _EscapeControls(logging.Filter):
    """Log lines cannot drive the terminal: control characters are escaped."""

    def filter(self, record: logging.LogRecord) -> bool:
        from ..core.types import escape_control

        try:
            message = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad format string is logging's business
            return True
        clean = escape_control(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, ensure_ascii=False, default=str)
    sys.stdout.write("\n")


def safe_text(value: Any, markup: bool = True) -> str:
    """``value`` as text that cannot drive the terminal: control characters escaped
    (``\\x1b``), and rich markup escaped unless ``markup`` is False (for
    ``print(..., markup=False)``). For every string that came from a user, a map or a
    server: queries, label names, heuristic outputs, plugin metadata."""
    from rich.markup import escape

    from ..core.types import escape_control

    text = escape_control(str(value))
    return escape(text) if markup else text


def console():
    from rich.console import Console

    return Console(highlight=False)
