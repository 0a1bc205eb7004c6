"""``quash bench``: the paper's ablation tables on a labelled map."""

from __future__ import annotations

import argparse

NAME = "bench"
HELP = (
    "Ablations as in the paper (prompt engineering, antonyms, synonym x antonym source, "
    "classifiers) and the fair protocol (every peer with the label list QuASH gets)."
)
ORDER = 34
DESCRIPTION = """\
Runs each ablation table with `quash eval`'s metrics and writes bench.md, bench.json and
one precision-vs-recall plot per table into --out. Every table says what each method
was given (the label list, or the query alone); the fair table runs the shipped peers'
rules and QuASH configs, the label-list ones on the same list (--taxonomy, else the map's
label names with the taxonomy beside the map). The llm source reads only its cache
(offline: true), the sets cached for --llm-model at --llm-base-url; a query missing from
it skips that row with a note naming the endpoint and model. Files in --out are
replaced only when they are previous bench outputs, or with --force."""
EPILOG = """\
examples:
  quash make-scene scene.npz --seed 1
  quash bench scene.npz --taxonomy scene.taxonomy.yaml --out bench/
  quash bench scene.npz --taxonomy scene.taxonomy.yaml --tables antonyms,classifiers
  quash bench scene.npz --taxonomy scene.taxonomy.yaml --queries-file scene.open-queries.yaml
  quash bench scene.npz --taxonomy scene.taxonomy.yaml --tables sources \\
      --llm-model llama3.1:8b --llm-base-url http://127.0.0.1:11434/v1"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..evaluation.ablations import TABLES
    from ..heuristics import LLM_DEFAULT_BASE_URL  # the llm heuristic's own default
    from ._backend_opts import add_backend_arguments

    p.add_argument("map", help="Labelled map (labels + label_names).")
    p.add_argument(
        "--taxonomy",
        metavar="FILE",
        default=None,
        help="Taxonomy YAML {label: [sub-class, ...]} (make-scene writes one). Needed by the "
        "taxonomy rows of the prompt and sources tables and by the classifiers table, which "
        "are skipped without it; the fair table then uses the map's label names with "
        "MAP.taxonomy.yaml beside the map.",
    )
    p.add_argument(
        "--out", metavar="DIR", default="quash-bench", help="Output folder (default: %(default)s)."
    )
    p.add_argument(
        "--tables", default=",".join(TABLES), help="Comma-separated subset of: %(default)s."
    )
    p.add_argument("--encoder", default="minilm", help="Encoder name (default: minilm).")
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--queries",
        metavar="A,B,...",
        default=None,
        help="Queries to score: labels, or TEXT=LABEL as in quash eval (default: every "
        "label present in the map). It splits at every comma: give a query text that "
        "holds a comma in --queries-file.",
    )
    g.add_argument(
        "--queries-file",
        metavar="FILE.yaml",
        default=None,
        help="Queries from a YAML file, as quash eval reads it: {present: {text: label} or "
        "[labels], absent: [texts]} (make-scene writes SCENE.queries.yaml and "
        "SCENE.open-queries.yaml); --absent adds to its absent list.",
    )
    p.add_argument(
        "--absent",
        metavar="X,Y,...",
        default=None,
        help="Absence queries: labels or free text that are not in the map.",
    )
    p.add_argument(
        "--llm-model",
        default=None,
        help="Model name of the cached llm query sets (the llm rows of the sources table; "
        "read from the cache only, never from a server).",
    )
    p.add_argument(
        "--llm-base-url",
        metavar="URL",
        default=None,
        help="The base_url the llm cache was filled from: cached sets are keyed by endpoint "
        f"and model (default: {LLM_DEFAULT_BASE_URL}; lseg:quash-llm and "
        "conceptfusion:quash-llm ask http://127.0.0.1:11434/v1).",
    )
    p.add_argument("--no-cache", action="store_true", help="Do not use the text-embedding cache.")
    p.add_argument(
        "--force",
        action="store_true",
        help="Replace files in --out that are not previous bench outputs (never an input).",
    )
    add_backend_arguments(p)


def _taxonomy_missing(spec: str) -> str:
    """A missing ``--taxonomy``: the files beside it with a near name and what to give."""
    from pathlib import Path

    from ..core.errors import near_paths

    near = near_paths(Path(spec), (".yaml", ".yml", ".json"))
    hint = f" Did you mean {' or '.join(near)}?" if near else ""
    return (
        f"Taxonomy file not found: {spec}.{hint} --taxonomy names it: give a YAML file of "
        "{label: [sub-class, ...]} (quash make-scene writes one, SCENE.taxonomy.yaml), or "
        "leave it out to skip the rows that need it."
    )


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..core.errors import UsageError
    from ..evaluation.ablations import TABLES, run_bench
    from ._backend_opts import backend_overrides
    from ._output import console, each_log_line_once, print_markdown, say_done
    from .cmd_eval import queries_from_options

    tables = tuple(t.strip() for t in args.tables.split(",") if t.strip())
    if not tables:
        raise UsageError(
            f"--tables is empty: name one or more of {', '.join(TABLES)}, or leave it out "
            "for every table."
        )
    bad = [t for t in tables if t not in TABLES]
    if bad:
        raise UsageError(f"Unknown table {bad[0]!r}; known: {', '.join(TABLES)}.")
    # read as quash eval reads them; a query file's mistakes before any work
    queries, absent, absent_in_file = queries_from_options(
        args.queries, args.queries_file, args.absent
    )
    if args.taxonomy and not Path(args.taxonomy).exists():
        raise UsageError(_taxonomy_missing(args.taxonomy))
    if args.llm_base_url and not args.llm_model:
        raise UsageError(
            "--llm-base-url needs --llm-model (the model whose cached query sets to read)."
        )
    llm = None
    if args.llm_model:
        llm = {"model": args.llm_model}
        if args.llm_base_url:
            llm["base_url"] = args.llm_base_url
    _check_outputs(args, Path(args.out), tables)
    overrides = backend_overrides(args)
    if args.no_cache:
        overrides["cache"] = False
    out = console()
    with each_log_line_once():
        run_bench(
            args.map,
            str(Path(args.taxonomy).resolve()) if args.taxonomy else None,
            args.out,
            tables=tables,
            encoder=args.encoder,
            llm=llm,
            overrides=overrides,
            queries=queries,
            absent=tuple(absent),
            query_file=args.queries_file,
            absent_in_file=absent_in_file,
            on_table=lambda t: say_done(args, f"table {t}: done"),  # progress
        )
    print_markdown(out, (Path(args.out) / "bench.md").read_text(encoding="utf-8"), Path(args.out))
    return 0


def _check_outputs(args: argparse.Namespace, outdir, tables) -> None:
    """Refuse, before any work, to replace inputs or files that bench did not write."""
    from ..core.atomic import check_output
    from ..core.errors import UsageError
    from ..evaluation.plot import is_plot_png
    from ..evaluation.report import is_report_file

    if outdir.exists() and not outdir.is_dir():
        raise UsageError(f"--out {outdir} exists and is not a folder. Choose a folder.")
    inputs = (args.map, args.taxonomy, args.queries_file)
    files = [("bench.md", is_report_file), ("bench.json", is_report_file)]
    files += [(f"{t}.png", is_plot_png) for t in tables]
    for name, known in files:
        check_output(outdir / name, inputs, what="--out", overwrite=args.force, replaceable=known)
