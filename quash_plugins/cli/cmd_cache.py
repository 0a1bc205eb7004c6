"""``quash cache``: inspect or clear the on-disk text-embedding cache."""

from __future__ import annotations

import argparse

NAME = "cache"
HELP = "Show or clear the text-embedding cache (quash cache info | clear)."
ORDER = 80
DESCRIPTION = """\
The text-embedding cache keeps every string's embedding, keyed by the encoder's
fingerprint (model, weights identity, normalisation) and the exact string, so a repeated
query makes no call to the model. Location: $QUASH_CACHE_DIR/text-embeddings, else the
user cache directory. Size bound: $QUASH_CACHE_MAX_MB (default 512). Turn it off for one
run with --no-cache (query, expand) or 'cache: false' in the config."""
EPILOG = """\
examples:
  quash cache info
  quash cache info --json
  quash cache clear"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="cache_command", metavar="ACTION")
    info = sub.add_parser("info", help="Location, size, bound and entries per encoder.")
    info.add_argument("--json", action="store_true", help="Print JSON instead of a table.")
    clear = sub.add_parser("clear", help="Delete cached text embeddings.")
    clear.add_argument(
        "--fingerprint", default=None, help="Only this encoder fingerprint (see 'cache info')."
    )
    for q in (info, clear):
        q.add_argument(
            "--dir", default=None, metavar="DIR", help="Cache directory (default: see above)."
        )


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GiB"


def run(args: argparse.Namespace) -> int:
    from ..core.errors import UsageError
    from ..engine.cache import TextEmbeddingCache
    from ._output import console, print_json, safe_text

    action = getattr(args, "cache_command", None)
    if action is None:
        raise UsageError("quash cache needs an action: info or clear (see quash cache --help).")
    cache = TextEmbeddingCache(args.dir)
    out = console()
    if action == "clear":
        freed = cache.clear(args.fingerprint)
        what = f"fingerprint {args.fingerprint}" if args.fingerprint else "all text embeddings"
        out.print(safe_text(f"cleared {what} from {cache.directory} ({_size(freed)} freed)"))
        return 0
    info = cache.info()
    if args.json:
        print_json(info)
        return 0
    out.print(f"directory: {safe_text(info['directory'])}")
    out.print(
        f"size: {_size(info['bytes'])} of {_size(info['max_bytes'])}, "
        f"{info['entries']} strings in {info['files']} files"
    )
    if info["encoders"]:
        import datetime

        from rich.table import Table

        table = Table(title="text embeddings by encoder fingerprint")
        for col in ("fingerprint", "strings", "size", "last used"):
            table.add_column(col, justify="left" if col == "fingerprint" else "right")
        for e in info["encoders"]:
            when = datetime.datetime.fromtimestamp(e["last_used"]).strftime("%Y-%m-%d %H:%M")
            table.add_row(safe_text(e["fingerprint"]), str(e["entries"]), _size(e["bytes"]), when)
        out.print(table)
    return 0
