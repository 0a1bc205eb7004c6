"""``quash eval``: score method configs against a map's ground-truth labels."""

from __future__ import annotations

import argparse
import logging
from typing import Any

NAME = "eval"
HELP = "Score configs on a labelled map: precision, recall, F1, IoU and absence queries."
ORDER = 30
log = logging.getLogger(__name__)
DESCRIPTION = """\
Scores each config's mask for every query against the map's ground truth
(labels == the query's label): precision, recall, F1 and IoU per query and their macro
mean, and from the scores the average precision (AP) and OpenLex3D's inverse rank.
Open-vocabulary queries name their ground-truth label: --queries "bunk bed=bed,somewhere
to sleep=bed" or --queries-file FILE.yaml. Unlabelled items (label < 0) and --exclude
labels count neither as TP nor FP. Queries whose label no item carries (warned about
unless given to --absent too), and every --absent query, are absence queries: their
score is the share that returns an empty mask (at most --empty-tolerance items); a
label that is a near miss of one of the map's names ('bedd') is refused as a typo. Each row says what the method was given (the
label list, or the query alone) and how many present queries it returned empty. With no
-c it runs the fair comparison: the default config beside VLMaps' rule over its category
list and OpenScene's label argmax, all given the same label list."""
EPILOG = """\
examples:
  quash make-scene scene.npz
  quash eval scene.npz                    # the default config and the fair peers
  quash eval scene.npz -c demo:vlmaps -c demo:quash-labels --all-labels \\
      --absent piano,bathtub --json eval.json --markdown eval.md --plot eval.png
  quash eval scene.npz -c quash-labels.yaml --queries "bunk bed=bed,somewhere to sleep=bed" \\
      --absent "an elephant"
  quash eval scene.npz -c quash-labels.yaml --queries-file scene.open-queries.yaml
A query file is {present: {text: label} or [labels], absent: [texts]}.
The JSON holds {"configs": [{"name", "given", "mean": {precision, recall, f1, iou, ap,
inv_rank} (null with no present query), "per_query": {query: {label, ...}}, "absence":
{score, empty_tolerance, present_empty, per_query: {query: {label (from the queries),
matched, empty}}}}], "provenance": {quash_plugins (the version), map: {path, adapter,
...}, query_file, queries: {text: label}, absent, absent_labels: {text: label},
configs: [{name, file, shipped, encoder}], exclude, empty_tolerance}}.
Outputs never replace an input; an existing file is replaced only when it is a previous
quash report, plot or quash recording, or with --force."""


def _split(text: str | None) -> list[str]:
    """The items of a comma-separated option, each with its spacing made single (as a
    query file's are), empty ones dropped."""
    return [" ".join(t.split()) for t in (text or "").split(",") if t.strip()]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..evaluation.report import DEFAULT_EXCLUDE
    from ._backend_opts import add_backend_arguments
    from ._config_opts import add_adapter_options, add_config_option, add_runtime_options
    from ._viewer_opts import add_viewer_arguments

    p.add_argument("map", help="Labelled map (labels + label_names), e.g. from make-scene.")
    add_config_option(p, multiple=True)
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--queries",
        metavar="A,B,...",
        help="Comma-separated queries to score: labels, or TEXT=LABEL for an "
        "open-vocabulary query with its ground-truth label ('bunk bed=bed'); a label "
        "matches the map's names ignoring case and spacing. It splits at every comma: "
        "give a query text that holds a comma in --queries-file. A query whose label no "
        "item of the map carries is scored as an absence query, with a warning unless it "
        "or its label is given to --absent.",
    )
    g.add_argument(
        "--queries-file",
        metavar="FILE.yaml",
        help="Queries from a YAML file {present: {text: label} or [labels], absent: "
        "[texts]} (make-scene writes SCENE.queries.yaml and SCENE.open-queries.yaml).",
    )
    g.add_argument(
        "--all-labels",
        action="store_true",
        help="Score every label present in the map (the default).",
    )
    p.add_argument(
        "--absent",
        metavar="X,Y,...",
        default=None,
        help="Absence queries: labels or free text that are not in the map (a label "
        "the map's items carry is refused).",
    )
    p.add_argument(
        "--exclude",
        metavar="NAMES",
        default=",".join(DEFAULT_EXCLUDE),
        help="Labels ignored in TP/FP and never queried, in any case or spacing (default: "
        "%(default)s).",
    )
    p.add_argument(
        "--empty-tolerance",
        type=int,
        default=0,
        metavar="N",
        help="An absence query counts as empty with at most N matches, and so does a present "
        "query in the present -> empty column (default 0).",
    )
    p.add_argument("--adapter", default=None, help="Adapter name (default: the first config's).")
    add_adapter_options(p)
    p.add_argument("--json", metavar="FILE", help="Write the report as JSON.")
    p.add_argument("--markdown", metavar="FILE", help="Write the comparison as Markdown.")
    p.add_argument("--plot", metavar="FILE.png", help="Plot precision vs recall per config.")
    p.add_argument(
        "--force",
        action="store_true",
        help="Let --json, --markdown, --plot and --rrd replace existing files that are not "
        "previous outputs of quash (never an input).",
    )
    add_runtime_options(p)
    add_viewer_arguments(
        p,
        "Log the evaluation to Rerun (needs the [rerun] extra): the map, each config's "
        "results in a tab of its own, coloured by outcome against the ground truth (true "
        "positives blue, false positives vermillion, false negatives yellow), each "
        "config's per-query F1, precision, recall, IoU and AP as plots, each absence query "
        "after them as 'absence' (1: it came back empty), and the comparison table.",
    )
    add_backend_arguments(p)


def run(args: argparse.Namespace) -> int:
    import json

    from ..core.atomic import atomic_write_text
    from ..core.progress import progress
    from ..engine.pipeline import Quash
    from ..evaluation.plot import plot_precision_recall
    from ..evaluation.report import evaluate
    from ._backend_opts import backend_overrides
    from ._config_opts import (
        FAIR_PEERS,
        adapter_options,
        apply_runtime_options,
        check_map_inputs,
        fair_default_configs,
        load_config,
    )
    from ._output import console, each_log_line_once, print_markdown, safe_text, say_done
    from ._viewer_opts import open_viewer

    if args.configs:
        configs = [load_config(c) for c in args.configs]
    else:
        log.info("no -c: the default config and the fair peers (%s)", ", ".join(FAIR_PEERS))
        configs = fair_default_configs()
    _check_outputs(args, configs)
    queries, absent, absent_in_file = _queries(args)  # a query file's mistakes before any work
    overrides = backend_overrides(args)
    quashes = [Quash.from_config(apply_runtime_options(cfg, args), **overrides) for cfg in configs]
    lmap = quashes[0].read_map(args.map, adapter=args.adapter, **adapter_options(args))
    flags = ("--json", "--markdown", "--plot", "--rrd")
    check_map_inputs(lmap, [(f, getattr(args, f[2:], None)) for f in flags])
    # Before the evaluation: a busy port is said before any work, and --serve-web's URL
    # can be opened meanwhile (docs/rerun.md).
    viewer = open_viewer(args, app_id="quash-eval")
    if viewer is not None:  # a live viewer shows the map while the configs run
        viewer.log_map(lmap)
    with (
        each_log_line_once(),
        progress(len(quashes), f"evaluating {len(quashes)} config(s)") as advance,
    ):
        report = evaluate(
            lmap,
            quashes,
            queries=queries,
            exclude=_split(args.exclude),
            absent=absent,
            empty_tolerance=args.empty_tolerance,
            on_query=lambda name, n: advance(1),
            query_file=args.queries_file,
            absent_in_file=absent_in_file,
            keep_results=viewer is not None,  # the masks, for the viewer only
        )
    if not report.absent:
        _warn_no_absence(args.map)
    if args.json:
        atomic_write_text(args.json, json.dumps(report.to_json(), indent=2) + "\n")
    md = report.to_markdown()
    if args.markdown:
        atomic_write_text(args.markdown, f"# quash eval: {lmap.describe()}\n\n{md}")
    if args.plot and not report.queries:
        log.warning("--plot %s not written: no present query to score", args.plot)
        args.plot = None
    if args.plot:
        plot_precision_recall(report.configs, args.plot, title=f"quash eval: {args.map}")
    if viewer is not None:
        viewer.log_report(lmap, report)
    out = console()
    out.print(
        safe_text(lmap.describe())
        + f": {_count(len(report.queries), 'query')}, "
        + _count(len(report.absent), "absence query")
    )
    print_markdown(out, md)
    for f in (args.json, args.markdown, args.plot):
        if f:
            say_done(args, f"wrote {f}")
    if viewer is not None:
        viewer.close()  # with --serve-web this serves until Ctrl-C or SIGTERM
    return 0


def _count(n: int, noun: str) -> str:
    """``1 query``, ``2 absence queries``."""
    return f"{n} {noun if n == 1 else noun[:-1] + 'ies'}"


def _warn_no_absence(map_path: str) -> None:
    """Say that a report with no absence query does not measure the empty answer, and
    name make-scene's query file beside the map where there is one (a map holds only the
    labels its items carry, so the absent ones must come from somewhere else)."""
    from ..demo.scene import scene_paths

    beside = scene_paths(map_path)["queries"]
    hint = (
        f"; {beside} beside the map lists the scene's absent labels: add --queries-file {beside}"
        if beside.is_file()
        else ""
    )
    log.warning(
        "no absence query: this report does not measure whether an absent object comes "
        "back empty (give --absent X,Y or a query file's absent list%s)",
        hint,
    )


def _queries(args: argparse.Namespace) -> tuple[Any, list[str], list[str]]:
    """The queries to score (None: every label), the absence queries, and those of them
    that came from the query file (the others came from --absent)."""
    from ..core.errors import UsageError

    if args.empty_tolerance < 0:
        raise UsageError("--empty-tolerance takes N >= 0 (items an empty mask may have).")
    return queries_from_options(args.queries, args.queries_file, args.absent)


def queries_from_options(
    queries_text: str | None, queries_file: str | None, absent_text: str | None
) -> tuple[Any, list[str], list[str]]:
    """What --queries, --queries-file and --absent give (``quash eval`` and ``quash
    bench`` read them alike): the queries (None: every label), the absence queries (the
    file's, then --absent's), and those that came from the file."""
    from ..core.errors import UsageError
    from ..evaluation.queries import read_query_file

    queries: Any = _split(queries_text) or None
    if queries_text is not None and not queries:
        raise UsageError(
            "--queries is empty: give labels or TEXT=LABEL items, or leave it out to score "
            "every label of the map."
        )
    absent, in_file = _split(absent_text), []
    if queries_file:
        queries, in_file, lookalikes = read_query_file(queries_file)
        absent = list(dict.fromkeys([*in_file, *absent]))
        for label, names in lookalikes.items():
            log.warning(
                "%s: the scene's appearance names %s read as the absent %r (make-scene's "
                "absent_lookalikes): a match of its absence queries may be the scene's "
                "features, not a method's mistake",
                queries_file,
                ", ".join(names),
                label,
            )
    return queries, absent, in_file


def _check_outputs(args: argparse.Namespace, configs=()) -> None:
    """Refuse, before any work, outputs that would replace an input or a user's file.

    The inputs are the map, the taxonomy beside it, the query file, the configs and the
    files they name (:func:`~._config_opts.input_files`); ``--force`` never lets an
    output replace one.
    """
    from ..core.atomic import check_distinct_outputs, check_output
    from ..evaluation.plot import is_plot_png
    from ..evaluation.report import is_report_file
    from ._config_opts import input_files
    from ._viewer_opts import check_rrd

    check_distinct_outputs(
        [("--json", args.json), ("--markdown", args.markdown), ("--plot", args.plot)]
        + [("--rrd", args.rrd)]
    )
    inputs = (
        args.map,
        *(args.configs or ()),
        *([args.queries_file] if args.queries_file else []),
        *input_files(args.map, list(configs)),
    )
    for flag, path, known in (
        ("--json", args.json, is_report_file),
        ("--markdown", args.markdown, is_report_file),
        ("--plot", args.plot, is_plot_png),
    ):
        if path:
            check_output(path, inputs, what=flag, overwrite=args.force, replaceable=known)
    check_rrd(args, inputs)
