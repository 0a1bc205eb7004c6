"""Helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

from ..config import QuashConfig
from ..errors import UsageError

log = logging.getLogger("quash_plugins.cli")


def setup_logging(verbose: int, quiet: bool) -> None:
    """Route ``quash_plugins`` logging to stderr through rich."""
    from rich.console import Console
    from rich.logging import RichHandler

    from .. import _progress

    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    _progress.QUIET = quiet
    handler = RichHandler(
        console=Console(stderr=True),
        show_time=False,
        show_path=verbose > 1,
        markup=False,
        rich_tracebacks=False,
    )
    root = logging.getLogger("quash_plugins")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


def add_config_option(parser: argparse.ArgumentParser, multiple: bool = False) -> None:
    if multiple:
        parser.add_argument(
            "-c",
            "--config",
            action="append",
            metavar="CONFIG",
            dest="configs",
            default=None,
            help="Method config (YAML); repeat to compare methods side by side.",
        )
    else:
        parser.add_argument(
            "-c",
            "--config",
            metavar="CONFIG",
            default=None,
            help="Method config (YAML). Default: minilm + none + nearest-sample.",
        )


def add_runtime_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--no-cache", action="store_true", help="Do not read or write the text-embedding cache."
    )
    parser.add_argument(
        "--device", default=None, help="Override the config's device (cpu, cuda, mps, auto)."
    )


def load_config(path: str | None) -> QuashConfig:
    if path is None:
        return QuashConfig()
    if not Path(path).exists():
        raise UsageError(f"Config file not found: {path}")
    return QuashConfig.from_yaml(path)


def apply_runtime_options(cfg: QuashConfig, args: argparse.Namespace) -> QuashConfig:
    if getattr(args, "no_cache", False):
        cfg.cache = False
    if getattr(args, "device", None):
        cfg.device = args.device
    return cfg


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, ensure_ascii=False, default=str)
    sys.stdout.write("\n")


def console():
    from rich.console import Console

    return Console(highlight=False)
