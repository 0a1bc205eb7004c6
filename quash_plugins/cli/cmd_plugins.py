"""``quash plugins``: every registered plugin and whether it loads."""

from __future__ import annotations

import argparse
from typing import Any

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


def config_name(info: Any, infos: list[Any]) -> str:
    """The name a config uses for ``info``: its bare name, or ``dist:name`` when another
    distribution claims the name too (a built-in keeps the bare name)."""
    from ..core.registry import BUILTIN_DIST

    others = [o for o in infos if o.kind == info.kind and o.name == info.name and o is not info]
    if not others or (info.dist == BUILTIN_DIST and all(o.dist != BUILTIN_DIST for o in others)):
        return info.name
    return info.qualified


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
        # Names are what a config spells: never cut them short with an ellipsis.
        table.add_column(col, no_wrap=col == "name", overflow="fold")
    broken = [i for i in infos if i.status != "ok"]
    kinds = list(registry.KINDS)
    builtin = registry.BUILTIN_DIST
    for i in sorted(infos, key=lambda i: (kinds.index(i.kind), i.name, i.dist != builtin)):
        status = "[green]ok[/]" if i.status == "ok" else f"[red]{safe_text(i.status)}[/]"
        name = config_name(i, infos)
        table.add_row(*(safe_text(x) for x in (i.kind, name, i.dist, i.version)), status)
    console().print(table)
    # The errors in full, after the table: in a table cell they would be cut to a few
    # words per line.
    for i in broken:
        console().print(
            f"[red]{safe_text(i.kind)} {safe_text(i.name)}[/] ({safe_text(i.dist)}): "
            f"{safe_text(i.error or i.status)}",
            highlight=False,
        )
    return 0
