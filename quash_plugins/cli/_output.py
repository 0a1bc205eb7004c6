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
    root = logging.getLogger("quash_plugins")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, ensure_ascii=False, default=str)
    sys.stdout.write("\n")


def console():
    from rich.console import Console

    return Console(highlight=False)
