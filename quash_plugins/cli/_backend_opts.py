"""Compute-backend options shared by query, eval and demo (owned by the scale module)."""

from __future__ import annotations

import argparse
from typing import Any


def add_backend_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("compute backend")
    g.add_argument(
        "--backend", choices=("numpy", "dask"), default="numpy",
        help="numpy: in-process chunks (default); dask: map_blocks on a Dask cluster.",
    )
    g.add_argument(
        "--scheduler", metavar="ADDRESS", default=None,
        help="Dask scheduler address (tcp://host:8786); default starts a LocalCluster.",
    )


def backend_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """Keyword overrides for :meth:`Quash.from_config` from the parsed options."""
    if getattr(args, "backend", "numpy") != "dask":
        return {}
    from ..scale import client_from_cli

    return {"backend": "dask", "client": client_from_cli(args.scheduler)}
