"""Rerun output options shared by query, eval and demo: flags to :class:`ViewerOptions`."""

from __future__ import annotations

import argparse
from typing import Any

from ..core.types import UP_CHOICES
from ..viewer import (
    DEFAULT_BIND,
    DEFAULT_GRPC_PORT,
    DEFAULT_WEB_PORT,
    ViewerOptions,
    check_bind,
    check_distinct_ports,
    check_port,
)


def _arg_type(check: Any, what: str) -> Any:
    """An argparse ``type`` from a checker that raises :class:`UsageError`."""

    def convert(text: str) -> Any:
        from ..core.errors import UsageError

        try:
            return check(text, what)
        except UsageError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix(f"{what} ")) from None

    convert.__name__ = what.lstrip("-").replace("-", " ")
    return convert


#: What ``quash query`` logs; the default description of the option group.
LOGS_QUERIES = "Log the map and every query to Rerun (needs the [rerun] extra)."


def add_viewer_arguments(parser: argparse.ArgumentParser, logs: str = LOGS_QUERIES) -> None:
    """Add ``--rrd``, ``--spawn``, ``--connect``, ``--serve-web``, ``--web-port``,
    ``--grpc-port``, ``--bind`` and ``--up`` (each command that logs to Rerun logs its map);
    ``logs`` says what the command logs (refilled to the terminal's width, as every
    description is: :class:`~quash_plugins.cli.main.HelpFormatter`)."""
    g = parser.add_argument_group("Rerun viewer", logs)
    g.add_argument(
        "--rrd",
        metavar="FILE.rrd",
        help="Write a Rerun recording to this file (atomically; open it with `rerun FILE.rrd`).",
    )
    g.add_argument(
        "--spawn",
        action="store_true",
        help="Open the native Rerun viewer (without a display: says so and carries on).",
    )
    g.add_argument(
        "--connect",
        metavar="URL",
        help="Stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy.",
    )
    g.add_argument(
        "--serve-web",
        action="store_true",
        help=f"Serve the web viewer on {DEFAULT_BIND} (see --bind), print its URL and keep "
        "serving until Ctrl-C or SIGTERM.",
    )
    g.add_argument(
        "--web-port",
        type=_arg_type(check_port, "--web-port"),
        default=None,
        metavar="PORT",
        help=f"HTTP port (1-65535) of the web viewer for --serve-web (default: "
        f"{DEFAULT_WEB_PORT}).",
    )
    g.add_argument(
        "--grpc-port",
        type=_arg_type(check_port, "--grpc-port"),
        default=None,
        metavar="PORT",
        help="gRPC port (1-65535) the web viewer reads the recording from (default: "
        f"{DEFAULT_GRPC_PORT}).",
    )
    g.add_argument(
        "--bind",
        type=_arg_type(check_bind, "--bind"),
        default=None,
        metavar="ADDR",
        help=f"IP address --serve-web listens on (default: {DEFAULT_BIND}, this machine only; "
        "localhost means 127.0.0.1; 0.0.0.0 serves every network interface: only on a "
        "network you trust).",
    )
    g.add_argument(
        "--up",
        choices=UP_CHOICES,
        default="auto",
        help="The map's up axis, which the views look down along and the ceiling is found "
        "on. auto (default): the one the map's format fixes (VLMaps camera-base maps: +y; "
        "mobile-base maps and 2023 grids: +z), else +z. Give it for a map whose format does "
        "not say, such as a ConceptFusion cloud in a y-up dataset frame. "
        "quash query also records it in --out (npz, zarr, openlex3d).",
    )


def check_rrd(args: argparse.Namespace, inputs: Any = ()) -> None:
    """Refuse, before any work, an ``--rrd`` that is an input, or that replaces a file
    other than a recording quash wrote (unless ``--force``): a recording of another
    application (a robot's own log) is refused naming its application id. With
    ``--serve-web``, one port for both servers is refused; without it, ``--web-port``,
    ``--grpc-port`` and ``--bind`` are (they would be ignored). An ``--rrd`` not named
    ``*.rrd`` and a ``--connect`` that is no viewer URL are refused here too, before the
    map is read."""
    from pathlib import Path

    from ..core.atomic import check_output
    from ..core.errors import UsageError
    from ..viewer import (
        check_connect_url,
        check_rrd_name,
        is_quash_app_id,
        is_rrd,
        rrd_application_ids,
    )

    if getattr(args, "serve_web", False):
        check_distinct_ports(getattr(args, "web_port", None), getattr(args, "grpc_port", None))
    else:  # a flag that would be ignored is refused
        given = [
            flag
            for flag, dest in (
                ("--web-port", "web_port"),
                ("--grpc-port", "grpc_port"),
                ("--bind", "bind"),
            )
            if getattr(args, dest, None) is not None
        ]
        if given:
            raise UsageError(
                f"{' and '.join(given)} only {'applies' if len(given) == 1 else 'apply'} to "
                "--serve-web, which was not given. Add --serve-web to serve the recording, or "
                f"leave {'it' if len(given) == 1 else 'them'} out."
            )
    if getattr(args, "connect", None):
        check_connect_url(args.connect)
    if not getattr(args, "rrd", None):
        return
    force = bool(getattr(args, "force", False))
    path = Path(args.rrd).expanduser()
    check_rrd_name(path)
    # the input and file-kind refusals; whether it may be replaced is decided below
    out = check_output(path, inputs, what="--rrd", overwrite=True)
    if force or not out.exists():
        return
    if is_rrd(out):
        ids = rrd_application_ids(out)  # read once: whether quash wrote it, and whose it is
        if ids and all(is_quash_app_id(i) for i in ids):
            return
        whose = (
            f"a Rerun recording of application id {', '.join(map(repr, ids))}"
            if ids
            else "a Rerun recording whose application id cannot be read"
        )
        raise UsageError(
            f"--rrd {out} is {whose}, not one quash wrote; refusing to replace it. Pass "
            "--force to replace it, or choose another file."
        )
    raise UsageError(
        f"--rrd {out} already exists and is not a Rerun recording; refusing to replace it. "
        "Pass --force to replace it, or choose another file."
    )


def viewer_options(args: argparse.Namespace) -> ViewerOptions:
    """The :class:`ViewerOptions` of the parsed flags."""
    return ViewerOptions(
        rrd=args.rrd,
        spawn=bool(args.spawn),
        connect=args.connect,
        serve_web=bool(args.serve_web),
        web_port=args.web_port,
        grpc_port=args.grpc_port,
        bind=args.bind,
        quiet=bool(getattr(args, "quiet", False)),  # --quiet: no "wrote FILE.rrd" line
    )


def viewer_requested(args: argparse.Namespace) -> bool:
    """True when any Rerun output option was given."""
    return viewer_options(args).requested


def open_viewer(args: argparse.Namespace, app_id: str = "quash") -> Any:
    """A viewer logger for the options given, or None when none was asked for."""
    from ..viewer import open_viewer as open_sinks

    return open_sinks(viewer_options(args), app_id=app_id, up=getattr(args, "up", "auto"))
