"""``quash expand``: show the positives and negatives a config makes of a query."""

from __future__ import annotations

import argparse

NAME = "expand"
HELP = "Expand a query into positives and negatives with a config's heuristic."
ORDER = 20


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ._common import add_config_option, add_runtime_options

    p.add_argument("query", help="The query text, e.g. 'chair'.")
    add_config_option(p)
    p.add_argument(
        "--map", metavar="MAP", help="Map to give the heuristic (labels, mined negatives)."
    )
    p.add_argument(
        "--json",
        action="store_true",
        help='Print {"query", "positives", "negatives", "provenance"} as JSON.',
    )
    add_runtime_options(p)


def run(args: argparse.Namespace) -> int:
    from ..pipeline import Quash
    from ._common import apply_runtime_options, console, load_config, print_json

    cfg = apply_runtime_options(load_config(args.config), args)
    quash = Quash.from_config(cfg)
    lmap = quash.read_map(args.map) if args.map else None
    qs = quash.expand(args.query, lmap)
    if args.json:
        print_json(qs.to_dict())
        return 0
    out = console()
    out.print(f"[bold]query[/]: {qs.query}")
    out.print(f"[bold green]positives[/] ({len(qs.positives)}): " + ", ".join(qs.positives))
    out.print(f"[bold red]negatives[/] ({len(qs.negatives)}): " + ", ".join(qs.negatives))
    prov = qs.provenance
    out.print(f"[dim]provenance: {prov}[/]")
    return 0
