"""Rerun output options shared by query, eval and demo (owned by the Rerun module)."""

from __future__ import annotations

import argparse
from typing import Any


def add_viewer_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--rrd``, ``--spawn``, ``--connect``, ``--serve-web``, ``--web-port``, ``--grpc-port``."""
    g = parser.add_argument_group(
        "Rerun viewer", "Log the map and every query to Rerun (needs the [rerun] extra)."
    )
    g.add_argument(
        "--rrd",
        metavar="FILE.rrd",
        help="Write a Rerun recording to this file (atomically; open it with `rerun FILE.rrd`).",
    )
    g.add_argument("--spawn", action="store_true", help="Open the native Rerun viewer.")
    g.add_argument(
        "--connect",
        metavar="URL",
        help="Stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy.",
    )
    g.add_argument(
        "--serve-web",
        action="store_true",
        help="Serve the web viewer on 127.0.0.1, print its URL and keep serving until Ctrl-C.",
    )
    g.add_argument(
        "--web-port",
        type=int,
        default=9090,
        metavar="PORT",
        help="HTTP port of the web viewer for --serve-web (default: 9090).",
    )
    g.add_argument(
        "--grpc-port",
        type=int,
        default=9876,
        metavar="PORT",
        help="gRPC port the web viewer reads the recording from (default: 9876).",
    )


def viewer_requested(args: argparse.Namespace) -> bool:
    """True when any Rerun output option was given."""
    return bool(args.rrd or args.spawn or args.connect or args.serve_web)


def open_viewer(args: argparse.Namespace, app_id: str = "quash") -> Any:
    """A viewer logger for the options given, or None when none was asked for."""
    if not viewer_requested(args):
        return None
    from ..viewer import viewer_from_cli

    return viewer_from_cli(args, app_id=app_id)
