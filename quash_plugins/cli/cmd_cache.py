"""``quash cache``: inspect or clear the on-disk caches: text embeddings, LLM query sets."""

from __future__ import annotations

import argparse

NAME = "cache"
HELP = "Show or clear the text-embedding and LLM caches (quash cache info | clear)."
ORDER = 80
DESCRIPTION = """\
The text-embedding cache keeps every string's embedding, keyed by the encoder's
fingerprint (model, weights identity, normalisation) and the exact string, so a repeated
query makes no call to the model. Location: $QUASH_CACHE_DIR/text-embeddings, else the
user cache directory. Size bound: $QUASH_CACHE_MAX_MB (default 512). Turn it off for one
run with --no-cache (query, expand, eval, demo, make-scene, bench), QUASH_NO_CACHE=1,
or 'cache: false' in the config.

The llm heuristic keeps each query set it got from the server (one JSON file per query,
model, endpoint, prompt version and counts), so a second run asks no server. Location:
$QUASH_CACHE_DIR/llm, else the user cache directory, or the config's cache_dir. 'quash
cache clear' keeps them; 'quash cache clear --llm' deletes them, so the next run asks
again."""
EPILOG = """\
examples:
  quash cache info
  quash cache info --json
  quash cache clear                       # text embeddings
  quash cache clear --llm                 # LLM query sets
  quash cache clear --llm --dir llm-cache # a config's cache_dir: llm-cache (from its folder)"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="cache_command", metavar="ACTION")
    info = sub.add_parser(
        "info",
        help="Location, size, bound and entries per encoder; the LLM query sets per model.",
    )
    info.add_argument("--json", action="store_true", help="Print JSON instead of a table.")
    clear = sub.add_parser(
        "clear", help="Delete cached text embeddings (--llm: the LLM query sets)."
    )
    clear.add_argument(
        "--fingerprint", default=None, help="Only this encoder fingerprint (see 'cache info')."
    )
    for q, what in (
        (info, "Only the LLM query sets."),
        (
            clear,
            "Delete the LLM query sets "
            "instead of text embeddings: the next run asks the server again.",
        ),
    ):
        q.add_argument("--llm", action="store_true", help=what)
        q.add_argument(
            "--dir",
            default=None,
            metavar="DIR",
            help="Text-embedding cache directory (default: $QUASH_CACHE_DIR/text-embeddings, "
            "else the user cache directory); given, only this folder is shown or cleared "
            "(no LLM query sets). With --llm, the LLM query-set folder (default: "
            "$QUASH_CACHE_DIR/llm, else the user cache directory; or a config's heuristic "
            "cache_dir).",
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
    from ..heuristics import llm_cache_info
    from ._output import console, print_json, safe_text

    action = getattr(args, "cache_command", None)
    if action is None:
        raise UsageError("quash cache needs an action: info or clear (see quash cache --help).")
    out = console()
    if args.llm:
        return _run_llm(args, action, out)
    cache = TextEmbeddingCache(args.dir)
    # --dir names one text-embedding folder: only what it holds is shown, not the
    # default LLM folder's query sets (those belong to no --dir)
    llm = None if args.dir else llm_cache_info()
    if action == "clear":
        if args.fingerprint is not None and not cache._dir(args.fingerprint).is_dir():
            from ..core.errors import UsageError

            known = cache.fingerprints()
            raise UsageError(
                f"No fingerprint {args.fingerprint!r} in {cache.directory}. "
                + (f"Cached: {', '.join(known)}." if known else "The cache holds none.")
            )
        freed = cache.clear(args.fingerprint)
        what = f"fingerprint {args.fingerprint}" if args.fingerprint else "all text embeddings"
        out.print(safe_text(f"cleared {what} from {cache.directory} ({_size(freed)} freed)"))
        if llm and llm["sets"]:
            out.print(
                safe_text(
                    f"kept {_sets(llm['sets'])} in {llm['directory']} (quash cache clear --llm "
                    "deletes them)"
                )
            )
        return 0
    info = cache.info()
    if args.json:
        print_json(info if llm is None else {**info, "llm": llm})
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
            # the fingerprint whole, never cut ("..."): 'clear --fingerprint' takes it
            table.add_column(
                col,
                justify="left" if col == "fingerprint" else "right",
                overflow="fold" if col == "fingerprint" else "ellipsis",
                no_wrap=col != "fingerprint",
            )
        for e in info["encoders"]:
            when = datetime.datetime.fromtimestamp(e["last_used"]).strftime("%Y-%m-%d %H:%M")
            table.add_row(safe_text(e["fingerprint"]), str(e["entries"]), _size(e["bytes"]), when)
        out.print(table)
    if llm is not None:
        _print_llm(llm, out)
    return 0


def _sets(n: int) -> str:
    return f"{n} LLM query set{'' if n == 1 else 's'}"


def _print_llm(llm: dict, out) -> None:
    from ._output import safe_text

    out.print(
        safe_text(f"LLM query sets: {llm['directory']}: {llm['sets']} ({_size(llm['bytes'])})")
    )
    for m in llm["models"]:
        out.print(safe_text(f"  {m['model']} at {m['endpoint']}: {m['sets']}"))


def _run_llm(args: argparse.Namespace, action: str, out) -> int:
    from ..core.errors import UsageError
    from ..heuristics import clear_llm_cache, llm_cache_info, llm_cache_root
    from ._output import print_json, safe_text

    if action == "clear":
        if args.fingerprint:
            raise UsageError("--fingerprint names a text-embedding encoder; not with --llm.")
        n, freed = clear_llm_cache(args.dir)
        where = llm_cache_root(args.dir)
        out.print(safe_text(f"cleared {_sets(n)} from {where} ({_size(freed)} freed)"))
        return 0
    llm = llm_cache_info(args.dir)
    if args.json:
        print_json(llm)
    else:
        _print_llm(llm, out)
    return 0
