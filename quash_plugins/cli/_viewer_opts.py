"""Rerun output options shared by query, eval and demo (owned by the Rerun module)."""

from __future__ import annotations

import argparse
from typing import Any


def add_viewer_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("Rerun viewer")
    g.add_argument("--rrd", metavar="FILE.rrd", help="Write a Rerun recording to this file.")
    g.add_argument("--spawn", action="store_true", help="Open the Rerun viewer.")
    g.add_argument("--connect", metavar="URL", help="Stream to a running Rerun viewer.")
    g.add_argument("--serve-web", action="store_true", help="Serve the web viewer.")


def open_viewer(args: argparse.Namespace, app_id: str = "quash") -> Any:
    """A viewer logger for the options given, or None when none was asked for."""
    if not (args.rrd or args.spawn or args.connect or args.serve_web):
        return None
    from ..viewer import viewer_from_cli

    return viewer_from_cli(args, app_id=app_id)
