"""``quash plugins``: every registered plugin and whether it loads."""

from __future__ import annotations

import argparse

NAME = "plugins"
HELP = "List encoders, heuristics, classifiers and adapters, with their distribution."
ORDER = 90


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="Print JSON instead of a table.")
    p.add_argument(
        "--kind",
        choices=("encoders", "heuristics", "classifiers", "adapters"),
        help="Only this kind.",
    )


def run(args: argparse.Namespace) -> int:
    from ..core import registry
    from ._output import console, print_json, safe_text

    infos = registry.plugins(args.kind, load=True)
    if args.json:
        print_json([i.to_dict() for i in infos])
        return 0
    from rich.table import Table

    table = Table(title="quash plugins")
    for col in ("kind", "name", "distribution", "version", "status"):
        table.add_column(col)
    for i in infos:
        status = (
            "[green]ok[/]"
            if i.status == "ok"
            else f"[red]{safe_text(i.status)}[/]: {safe_text(i.error or '')}"
        )
        table.add_row(*(safe_text(x) for x in (i.kind, i.name, i.dist, i.version)), status)
    console().print(table)
    return 0
