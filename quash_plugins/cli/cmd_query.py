"""``quash query``: answer text queries against a map."""

from __future__ import annotations

import argparse
import time

NAME = "query"
HELP = "Answer queries against a map; print matches, write masks and scores."
ORDER = 10
EPILOG = """\
examples:
  quash query vlmap/vlmaps.h5df chair sofa -c quash.yaml --out result.npz
  quash query map.npz chair --adapter npz --rrd chair.rrd
  quash query map.npz chair sofa -c quash.yaml --out chair-sofa --format openlex3d
The --out file holds queries (Q,) str, masks (Q, N) bool, scores (Q, N) float32 and
display_scores (Q, N) float32 in [0, 1] (row i: the map's item i), the map's positions
and grid_index where it has them (a pixel map: frame_ids, frame_hw and frame_offsets,
for masks_per_frame), the positions' up axis (up, a 0-d string: --up, else the one
the map's format records, if any), and provenance (a JSON string: version, map, config,
encoder fingerprint, each query's positives, negatives, heuristic with its parameters
(an llm's model and endpoint, and whether the set came from the server or the cache;
a label list's label, resolution and labels_from) and presence decision). With --out RESULT.zarr the same masks and
scores (the config's refine and presence applied) stream to a zarr store, without
display_scores (a pixel map's frame_ids, frame_hw and frame_offsets are attributes,
for frames_from_zarr, and so is up, as in the NPZ, for up_from_zarr), for maps larger than memory: the embeddings are read in chunks; with
refine or presence about 13 bytes per item are held per query of a group, queries
answered in groups that fit chunk_mb (see docs/scale.md).
With --format openlex3d, --out is a folder of per-query files aligned with the points
(point_cloud.pcd) of an OpenLex3D export of the map (quash convert MAP DIR --format
openlex3d; a map without positions, a pixel map, has none and is refused before any
query runs):
query_scores.npy (N, Q) in [0, 1] (0.5 at the threshold), query_scores_raw.npy,
query_masks.npy and queries.json (see docs/adapters.md#openlex3d).
--out and --rrd never replace the map or any other input, and never name one file;
an existing file is replaced only when it is a previous output of the same kind (a
query result, a quash recording), or with --force."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ._backend_opts import add_backend_arguments
    from ._config_opts import add_adapter_options, add_config_option, add_runtime_options
    from ._viewer_opts import add_viewer_arguments

    p.add_argument("map", help="Map file or directory.")
    p.add_argument("queries", nargs="+", metavar="QUERY", help="One or more queries.")
    add_config_option(p)
    p.add_argument(
        "--adapter",
        default=None,
        help="Adapter name, or 'auto' to sniff the format (default: the config's).",
    )
    add_adapter_options(p)
    p.add_argument(
        "--out", metavar="RESULT.npz|.zarr|DIR", help="Write masks and scores (atomically)."
    )
    p.add_argument(
        "--format",
        default="auto",
        choices=("auto", "npz", "zarr", "openlex3d"),
        help="Format of --out (default: auto, by its suffix, .npz or .zarr). openlex3d: a folder of "
        "per-query scores and masks aligned with an OpenLex3D export of the map (a map "
        "with positions; a pixel map is refused).",
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="Let --out and --rrd replace an existing file that is not a previous output "
        "of the same kind (never an input).",
    )
    p.add_argument("--json", action="store_true", help="Print the per-query summary as JSON.")
    add_runtime_options(p)
    add_viewer_arguments(p)
    add_backend_arguments(p)


def run(args: argparse.Namespace) -> int:
    from ..core.progress import progress
    from ..engine.pipeline import Quash
    from ..engine.results import write_results_npz
    from ._backend_opts import backend_overrides
    from ._config_opts import (
        adapter_options,
        apply_runtime_options,
        check_map_inputs,
        load_config,
    )
    from ._viewer_opts import open_viewer

    if args.format != "auto" and not args.out:
        from ..core.errors import UsageError

        raise UsageError(f"--format {args.format} is the format of --out: give --out too.")
    cfg = apply_runtime_options(load_config(args.config), args)
    options = adapter_options(args)
    _check_outputs(args, cfg)
    quash = Quash.from_config(cfg, **backend_overrides(args))
    if args.out and _out_format(args) == "zarr":
        return _query_to_zarr(args, quash)
    t_read = time.perf_counter()
    lmap = quash.read_map(args.map, adapter=args.adapter, **options)
    t_read = time.perf_counter() - t_read
    check_map_inputs(lmap, [("--out", args.out), ("--rrd", getattr(args, "rrd", None))])
    if args.out and _out_format(args) == "openlex3d":  # refused before any query runs
        from ..adapters import check_openlex3d_exportable

        check_openlex3d_exportable(
            lmap,
            " Such a map has no OpenLex3D export to align --format openlex3d results with "
            "(quash convert --format openlex3d refuses it too); write --out RESULT.npz "
            "(masks_per_frame cuts its masks per frame).",
        )
    # Before the queries: a busy port is said before any work, the map shows while they
    # run, and --serve-web's URL can be opened meanwhile (docs/rerun.md).
    viewer = open_viewer(args, app_id="quash-query")
    if viewer is not None:
        viewer.log_map(lmap)
    passes = f" ({quash.passes} passes)" if quash.passes > 1 else ""
    with progress(lmap.n * quash.passes, f"classifying {lmap.n} items{passes}") as advance:
        results = quash.query_many(lmap, args.queries, progress=advance)
    for r in results:  # the map was read here, before query_many: its share of that read
        r.timings["total"] += t_read / len(results) - r.timings.get("read", 0.0)
        r.timings["read"] = t_read / len(results)
    up = None if args.up == "auto" else args.up  # else the map's own, where it records one
    if args.out and _out_format(args) == "openlex3d":
        from ..engine.results import write_results_openlex3d

        write_results_openlex3d(args.out, results, {**lmap.source, **({"up": up} if up else {})})
    elif args.out:
        write_results_npz(
            args.out, results, lmap=lmap, encoder=quash.encoder, config_file=cfg.source, up=up
        )
    if viewer is not None:
        for i, r in enumerate(results):
            viewer.log_result(lmap, r, index=i)
    try:
        _report(args, cfg, lmap, results)
    finally:
        if viewer is not None:
            viewer.close()  # with --serve-web this serves until Ctrl-C
    return 0


def _out_suffix(args: argparse.Namespace) -> str | None:
    """``zarr`` or ``npz`` by the suffix of ``--out`` (any case), else None."""
    out = str(args.out).rstrip("/").lower()
    return "zarr" if out.endswith(".zarr") else "npz" if out.endswith(".npz") else None


def _out_format(args: argparse.Namespace) -> str:
    """``npz``, ``zarr`` or ``openlex3d``: ``--format``, else by the suffix of ``--out``."""
    fmt = getattr(args, "format", "auto") or "auto"
    return fmt if fmt != "auto" else _out_suffix(args) or "npz"


def _check_out_name(args: argparse.Namespace) -> None:
    """Refuse an ``--out`` whose name does not say its format: a suffix other than
    ``.npz`` or ``.zarr`` without ``--format``, or one that contradicts it."""
    from ..core.errors import UsageError

    fmt, suffix = getattr(args, "format", "auto") or "auto", _out_suffix(args)
    if fmt == "auto" and suffix is None:
        raise UsageError(
            f"--out {args.out}: name a results file RESULT.npz or a store RESULT.zarr, or "
            "pass --format (npz, zarr, openlex3d) to write that format under this name."
        )
    if fmt != "auto" and suffix is not None and suffix != fmt:
        raise UsageError(
            f"--out {args.out} names a .{suffix} but --format is {fmt}: change the "
            "suffix or the format, so that the file is what its name says."
        )


def _check_outputs(args: argparse.Namespace, cfg=None) -> None:
    """Refuse, before any work, outputs that would replace an input or a user's file.

    The inputs are the map, the taxonomy beside it, the config and the files it names
    (:func:`~._config_opts.input_files`); ``--force`` never lets an output replace one.
    """
    from ..core.atomic import check_distinct_outputs, check_output
    from ..engine.results import is_openlex3d_results, is_results_npz, is_results_zarr
    from ._config_opts import input_files
    from ._viewer_opts import check_rrd

    check_distinct_outputs([("--out", args.out), ("--rrd", getattr(args, "rrd", None))])
    inputs = (args.map, args.config, *input_files(args.map, [cfg] if cfg is not None else []))
    if args.out:
        fmt = _out_format(args)
        replaceable = {
            "zarr": is_results_zarr,
            "openlex3d": is_openlex3d_results,
            "npz": is_results_npz,
        }[fmt]
        check_output(
            args.out,
            inputs,
            what="--out",
            overwrite=args.force,
            replaceable=replaceable,
            folder=fmt != "npz",
        )
        _check_out_name(args)  # after: an output that is an input is the first thing to say
    check_rrd(args, inputs)


def _query_to_zarr(args, quash) -> int:
    """Results too large for memory: masks and scores stream into zarr, the same as
    ``query_many``'s (``LazyQuery.to_zarr`` applies the config's refine and presence)."""
    from ..core.errors import UsageError
    from ._config_opts import adapter_options
    from ._output import console, print_json, safe_text, say_done
    from ._viewer_opts import viewer_requested

    if viewer_requested(args):
        raise UsageError(
            "--out *.zarr streams results to disk; drop the Rerun options or use .npz."
        )
    lazy = quash.query_many_lazy(
        args.map, args.queries, adapter=args.adapter, **adapter_options(args)
    )
    path = lazy.to_zarr(args.out, up=None if args.up == "auto" else args.up)
    import dask.array as da
    import zarr

    store = zarr.open_group(str(path), mode="r")
    counts = da.from_zarr(store["masks"]).sum(axis=1).compute().tolist()
    n = int(store["masks"].shape[1])
    from ..core.presence_text import presence_words

    sets = list(store.attrs.get("querysets") or [{}] * len(counts))
    rows = [
        {
            "query": q,
            "matched": int(c),
            "share": c / max(1, n),
            "presence": presence_words(dict(qs.get("provenance") or {})),
        }
        for q, c, qs in zip(args.queries, counts, sets)
    ]
    if args.json:
        print_json({"n": n, "out": str(path), "results": rows})
        return 0
    out = console()
    for r in rows:
        said = "" if r["presence"] == "off" else f"; presence: {r['presence']}"
        out.print(
            f"{safe_text(r['query'])}: {r['matched']} of {n} items ({100 * r['share']:.2f}%)"
            f"{safe_text(said)}"
        )
    say_done(args, f"wrote {path}")
    return 0


def _report(args, cfg, lmap, results) -> None:

    from ._output import console, print_json, safe_text, say_done, timings_table

    if args.json:
        print_json(
            {
                "map": lmap.source,
                "n": lmap.n,
                "config": cfg.name,
                "results": [r.summary() for r in results],
            }
        )
        return
    from rich import box
    from rich.table import Table

    table = Table(
        title=safe_text(f"{lmap.describe()} | config {cfg.name}"),
        box=box.SIMPLE_HEAD,
        show_edge=False,
        pad_edge=False,
    )
    checked = any(r.presence != "off" for r in results)
    cols = ("query", "matched", "share", "instances", "positives", "negatives", "time")
    for col in (*cols, *(("presence",) if checked else ())):
        table.add_column(col, justify="left" if col in ("query", "presence") else "right")
    for r in results:
        cells = [
            safe_text(r.query),
            f"{r.n_matched}",
            f"{100 * r.share:.2f}%",
            "off" if r.n_instances is None else str(r.n_instances),
            f"{len(r.queryset.positives)}",
            f"{len(r.queryset.negatives)}",
            f"{r.timings.get('total', 0.0) * 1000:.0f} ms",
        ]
        if checked:
            cells.append(r.presence.split(" (", 1)[0].split(":", 1)[0])
        table.add_row(*cells)
    out = console()
    out.print(table)
    for r in results:  # an empty mask says why (docs/evaluation.md#the-presence-check)
        if (reason := r.emptied_by_presence) is not None:
            out.print(
                safe_text(f"{r.query!r} came back empty: {reason}; presence: null in the config ")
                + "keeps every match"
            )
        elif (reason := r.under_threshold) is not None:
            out.print(
                safe_text(f"{r.query!r} matched nothing: {reason}; ")
                + "'threshold:' in the config sets it"
            )
    out.print(timings_table(results, width=out.width))
    if args.out:
        say_done(args, f"wrote {args.out}")
