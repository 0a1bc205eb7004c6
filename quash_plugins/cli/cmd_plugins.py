"""``quash plugins``: every registered plugin and whether it loads."""

from __future__ import annotations

import argparse
from typing import Any

NAME = "plugins"
KINDS = ("encoders", "heuristics", "classifiers", "adapters")
HELP = "List encoders, heuristics, classifiers and adapters, with their distribution."
ORDER = 90


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="Print JSON instead of a table.")
    p.add_argument(
        "--kind",
        choices=KINDS,
        type=_kind,
        help="Only this kind (the singular, as a config section names it, is accepted too).",
    )


def _kind(text: str) -> str:
    """``encoder`` and ``Encoders`` read as ``encoders``, as the registry reads a kind (a
    config's sections are singular); anything else is left for argparse to refuse as typed."""
    from ..core.errors import PluginError
    from ..core.registry import normalize_kind

    try:
        return normalize_kind(text)
    except PluginError:
        return text


def config_name(info: Any, infos: list[Any]) -> str:
    """The name a config uses for ``info``: its bare name, or ``dist:name`` when another
    distribution claims the name too (a built-in keeps the bare name)."""
    from ..core.registry import BUILTIN_DIST

    others = [o for o in infos if o.kind == info.kind and o.name == info.name and o is not info]
    if not others or (info.dist == BUILTIN_DIST and all(o.dist != BUILTIN_DIST for o in others)):
        return info.name
    return info.qualified


def version_text(info: Any) -> str:
    """The version column of ``info``: its distribution's version, followed by
    ``(editable)`` when that distribution is an editable install (``pip install -e``) or
    a source tree found first, whose version does not name its code."""
    return f"{info.version} (editable)" if info.editable else info.version


def shadowed_by(info: Any, infos: list[Any]) -> str | None:
    """The built-in that keeps ``info``'s bare name, when ``info`` is another
    distribution's plugin of that name; else None."""
    from ..core.registry import BUILTIN_DIST

    if info.dist == BUILTIN_DIST:
        return None
    for o in infos:
        if o.kind == info.kind and o.name == info.name and o.dist == BUILTIN_DIST:
            return o.qualified
    return None


def run(args: argparse.Namespace) -> int:
    import contextlib
    import logging
    import sys

    from ..core import registry
    from ._output import console, print_json, safe_text

    # Errors are printed in full below the table: the registry's warnings would say
    # each one twice.
    reg_log = logging.getLogger(registry.__name__)
    level = reg_log.level
    reg_log.setLevel(logging.ERROR)
    try:
        # What a plugin module prints when imported (a banner) goes to stderr: stdout
        # holds the table, or the JSON a script reads.
        with contextlib.redirect_stdout(sys.stderr):
            infos = registry.plugins(args.kind, load=True)
    finally:
        reg_log.setLevel(level)
    by = {id(i): shadowed_by(i, infos) for i in infos}  # the built-in hiding each, if any
    if args.json:
        rows = []
        for i in infos:
            row = i.to_dict()
            row["config_name"] = config_name(i, infos)
            row["shadowed_by"] = by[id(i)]
            rows.append(row)
        print_json(rows)
        return 0
    from rich import box
    from rich.table import Table

    # as 'quash configs' does: no vertical rules, so a row of a built-in ('0.1.0
    # (editable)') fits 80 columns on one line (boxed, each row took two)
    table = Table(title="quash plugins", box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False)
    for col in ("kind", "name", "distribution", "version", "status"):
        # Names are what a config spells: never cut them short with an ellipsis.
        table.add_column(col, no_wrap=col == "name", overflow="fold")
    broken = [i for i in infos if i.status != "ok"]
    kinds = list(registry.KINDS)
    builtin = registry.BUILTIN_DIST
    for i in sorted(infos, key=lambda i: (kinds.index(i.kind), i.name, i.dist != builtin)):
        if i.status != "ok":
            status = f"[red]{safe_text(i.status)}[/]"
        elif by[id(i)]:
            status = "[yellow]ok, shadowed[/]"
        else:
            status = "[green]ok[/]"
        name = config_name(i, infos)
        cells = (i.kind, name, i.dist, version_text(i))
        table.add_row(*(safe_text(x) for x in cells), status)
    console().print(table)
    for i in (i for i in infos if by[id(i)]):
        console().print(
            f"[yellow]{safe_text(i.kind)} {safe_text(i.name)}[/] ({safe_text(i.dist)}): the "
            f"built-in {safe_text(by[id(i)])} keeps the name {safe_text(i.name)!r}; a config reaches "
            f"this one as {safe_text(i.qualified)!r}. Rename it in {safe_text(i.dist)}'s "
            "entry points to give it a name of its own.",
            highlight=False,
        )
    # An entry point in a group we do not read is invisible otherwise.
    wanted = {registry.GROUP_PREFIX + k for k in ([args.kind] if args.kind else kinds)}
    for m in registry.misplaced_entry_points():
        if m.meant is None or m.meant in wanted:
            console().print(
                f"[red]not read: {safe_text(m.name)}[/] ({safe_text(m.dist)}): "
                f"{safe_text(m.message())}",
                highlight=False,
            )
    # The errors in full, after the table: in a table cell they would be cut to a few
    # words per line.
    for i in broken:
        console().print(
            f"[red]{safe_text(i.kind)} {safe_text(i.name)}[/] ({safe_text(i.dist)}): "
            f"{safe_text(i.error or i.status)}",
            highlight=False,
        )
        if getattr(args, "debug", False) and i.exception is not None:
            import traceback

            # to stderr, unwrapped, as Python prints a traceback
            text = "".join(traceback.format_exception(i.exception))
            print(safe_text(text, markup=False), file=sys.stderr)
    if broken and not getattr(args, "debug", False):
        console().print("Run 'quash plugins --debug' for each error's traceback.")
    return 0
