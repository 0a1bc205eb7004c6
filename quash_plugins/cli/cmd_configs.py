"""``quash configs``: the method configs shipped with the package, by name."""

from __future__ import annotations

import argparse

NAME = "configs"
HELP = "List the shipped method configs (use one with -c NAME), or print one."
ORDER = 40
#: Under this many columns the list is one block per config, not a table.
NARROW = 100
DESCRIPTION = """\
The package ships method configs that any command takes by name (-c demo:quash-taxonomy).
demo:* ones use the shipped MiniLM encoder and run offline, on the demo scene or on any
map from 'quash make-scene'. The others use the encoder a real map was built with and
say what they need (downloaded weights, an LLM server): a map must be queried with the
text encoder that built it."""
EPILOG = """\
examples:
  quash configs                                  # name, needs (encoder), description
  quash configs demo:quash-taxonomy              # print one (its path, then the YAML)
  quash query scene.npz chair -c demo:quash-taxonomy"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "name",
        nargs="?",
        help="Print this config: its path, then its YAML with the files it names given whole.",
    )
    p.add_argument("--json", action="store_true", help="Print the list as JSON.")


def run(args: argparse.Namespace) -> int:
    from ..core.shipped import find_shipped, shipped_configs
    from ._output import console, print_json

    if args.name:
        from ..core.errors import ConfigError, UsageError

        try:
            cfg = find_shipped(args.name)
        except ConfigError as exc:
            raise UsageError(str(exc)) from None
        print(f"# {cfg.name}: {cfg.path}")
        print("# (files it names are given whole, so a copy of this text works anywhere)")
        print(cfg.portable_text(), end="")
        return 0
    configs = shipped_configs()
    if args.json:
        print_json(
            [
                {
                    "name": c.name,
                    "encoder": c.encoder,
                    "offline": c.offline,
                    "needs": c.needs,
                    "description": c.description,
                    "path": str(c.path),
                }
                for c in configs
            ]
        )
        return 0
    import textwrap

    from rich import box
    from rich.table import Table
    from rich.text import Text

    out = console()
    rows = []
    for c in sorted(configs, key=lambda c: (not c.offline, c.name)):
        needs = (
            Text("nothing (offline, MiniLM)", style="green")
            if c.offline
            else Text(c.needs or "", style="yellow")
        )
        rows.append((c, needs))
    title = "Shipped method configs: use one with -c NAME"
    if out.width < NARROW:
        # three columns in under 100 left the description some 20 characters (a path in
        # it cut with an ellipsis): each config is its name and needs, then its text
        out.print(f"[bold]{title}[/]")
        for c, needs in rows:
            out.print()
            out.print(Text.assemble((c.name, "bold"), "  needs ", needs), overflow="fold")
            for line in textwrap.wrap(c.description, width=max(20, out.width - 4)):
                out.print(Text("    " + line))
        return 0
    table = Table(title=title, title_justify="left", box=box.SIMPLE_HEAD)
    table.add_column("name", no_wrap=True, style="bold")
    table.add_column("needs", overflow="fold")
    table.add_column("description", ratio=1, overflow="fold")
    for c, needs in rows:
        table.add_row(Text(c.name), needs, Text(c.description))
    out.print(table)
    return 0
