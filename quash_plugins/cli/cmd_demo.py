"""``quash demo``: the peers' rules against QuASH on the cached offline proxy scene."""

from __future__ import annotations

import argparse

NAME = "demo"
HELP = "Offline demo: VLMaps, ConceptFusion, LERF and QuASH on a generated 3D scene."
ORDER = 5
DESCRIPTION = """\
Builds (once, cached under $QUASH_CACHE_DIR/demo or the user cache dir) a
labelled 3D indoor scene embedded with the shipped MiniLM model, then runs ten
methods on ten queries and three absence queries: the VLMaps, ConceptFusion and
LERF rules (one negative word each), VLMaps' and OpenScene's argmax over the
scene's label list (what QuASH's label and taxonomy heuristics see), and QuASH
with the labels, taxonomy (nearest-sample, and the paper's SVM), vocabulary and
adjectives heuristics. Prints the comparison, writes demo.md, demo.json,
demo.png and demo.rrd into --out. Needs no network. The method configs are
package data; --list-configs prints their paths ('quash configs' lists every
shipped config by name). Files in --out are replaced only when they are
previous demo outputs, or with --force. --serve-web serves the recording to a
browser on 127.0.0.1 until Ctrl-C or SIGTERM; the viewer opens on the best
method's tab, the rooms seen from above."""
EPILOG = """\
examples:
  quash demo                      # writes ./quash-demo/demo.{md,json,png,rrd}
  quash demo --spawn              # and opens the Rerun viewer (a desktop)
  quash demo --serve-web          # or serves it to a browser on 127.0.0.1
  quash demo --out /tmp/d --tiny  # a small scene, seconds"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ._backend_opts import add_backend_arguments
    from ._viewer_opts import add_viewer_arguments

    p.add_argument(
        "--out", default="quash-demo", metavar="DIR", help="Output folder (default: ./quash-demo)."
    )
    p.add_argument("--tiny", action="store_true", help="A small scene (tests, slow machines).")
    p.add_argument("--seed", type=int, default=0, help="Scene seed (default 0).")
    p.add_argument("--no-rrd", action="store_true", help="Do not write demo.rrd.")
    p.add_argument("--no-cache", action="store_true", help="Do not use the text-embedding cache.")
    p.add_argument(
        "--list-configs", action="store_true", help="Print the shipped demo config paths and exit."
    )
    p.add_argument(
        "--force",
        action="store_true",
        help="Replace files in --out that are not previous demo outputs.",
    )
    add_viewer_arguments(
        p,
        "Log the scene, every method's query results and the evaluation to Rerun (needs "
        "the [rerun] extra).",
    )
    add_backend_arguments(p)


def run(args: argparse.Namespace) -> int:
    import json
    import time
    from pathlib import Path

    from ..core.atomic import atomic_write_text, make_output_folder
    from ..demo.runner import demo_config_paths, run_demo
    from ..evaluation.plot import plot_precision_recall
    from ._backend_opts import backend_overrides
    from ._output import console, print_markdown, safe_text, say_done
    from ._viewer_opts import open_viewer

    if args.list_configs:
        # plain lines, one path each: never wrapped or parsed as markup (pipe-friendly)
        for path in demo_config_paths():
            print(path)
        return 0
    out = console()
    t0 = time.perf_counter()
    outdir = Path(args.out)
    if not args.no_rrd and not args.rrd:
        args.rrd = str(outdir / "demo.rrd")
    _check_outputs(args, outdir)
    _check_rerun(args, outdir)
    make_output_folder(outdir, "--out")
    overrides = backend_overrides(args)
    if args.no_cache:
        overrides["cache"] = False
    viewer = open_viewer(args, app_id="quash-demo")
    report, scene = run_demo(tiny=args.tiny, seed=args.seed, overrides=overrides, viewer=viewer)
    md = report.to_markdown()
    title = f"quash demo: {len(report.queries)} queries, {len(report.absent)} absence queries"
    atomic_write_text(outdir / "demo.md", f"# {title}\n\nScene: {scene}\n\n{md}")
    atomic_write_text(outdir / "demo.json", json.dumps(report.to_json(), indent=2) + "\n")
    plot_precision_recall(report.configs, outdir / "demo.png", title=title)
    out.print(f"[bold]{title}[/]")
    out.print(f"scene: {safe_text(scene)}")  # a path: its '[v1]' is no markup
    print_markdown(out, md)
    written = ", ".join(str(outdir / w) for w in ("demo.md", "demo.json", "demo.png"))
    say_done(args, f"wrote {written} in {time.perf_counter() - t0:.1f} s")
    if viewer is not None:
        # says "wrote DEMO.rrd" itself (the recording's one announcement, wherever --rrd
        # put it); with --serve-web it then serves until Ctrl-C or SIGTERM
        viewer.close()
    return 0


def _check_rerun(args: argparse.Namespace, outdir) -> None:
    """Refuse, before any work, Rerun output without the rerun SDK, saying how to run
    the demo without it (``--no-rrd``)."""
    from ..core.errors import QuashError, UsageError
    from ..viewer import import_rerun
    from ._viewer_opts import viewer_requested

    if not viewer_requested(args):
        return
    try:
        import_rerun()
    except QuashError:
        default = str(outdir / "demo.rrd")
        only_default = str(args.rrd) == default and not (
            args.spawn or args.connect or args.serve_web
        )
        fix = (
            "or pass --no-rrd to write demo.md, demo.json and demo.png without the recording"
            if only_default
            else "or drop the Rerun options (--rrd, --spawn, --connect, --serve-web) and "
            "pass --no-rrd to write demo.md, demo.json and demo.png only"
        )
        raise UsageError(
            f"quash demo writes its recording {args.rrd or '(streamed)'} with the rerun SDK, "
            f'which is not installed: pip install "quash-plugins[rerun]", {fix}.'
        ) from None


def _check_outputs(args: argparse.Namespace, outdir) -> None:
    """Refuse, before any work, to replace files in --out that the demo did not write."""
    from ..core.atomic import check_distinct_outputs, check_output
    from ..core.errors import UsageError
    from ..evaluation.plot import is_plot_png
    from ..evaluation.report import is_report_file
    from ._viewer_opts import check_rrd

    if outdir.exists() and not outdir.is_dir():
        raise UsageError(f"--out {outdir} exists and is not a folder. Choose a folder.")
    names = ("demo.md", "demo.json", "demo.png")
    check_distinct_outputs([*(("--out", outdir / n) for n in names), ("--rrd", args.rrd)])
    for name, known in (
        ("demo.md", is_report_file),
        ("demo.json", is_report_file),
        ("demo.png", is_plot_png),
    ):
        check_output(outdir / name, (), what="--out", overwrite=args.force, replaceable=known)
    check_rrd(args)
