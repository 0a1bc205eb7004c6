"""``quash``: query visual-language maps with QuASH.

Subcommands are discovered from the ``cmd_*`` modules of this package. Each defines
``NAME``, ``HELP``, ``ORDER``, ``add_arguments(parser)`` and ``run(args) -> int``.

Exit status: 0 on success, 2 for usage errors, 1 for other errors, 130 after Ctrl-C and
143 after SIGTERM. Errors print one message and no traceback unless ``--debug`` is given.
SIGTERM is turned into an exception, as Ctrl-C is, so that every temporary file of an
unfinished output is removed before the process exits; SIGINT works also when a shell
started the command in the background with SIGINT ignored.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import os
import pkgutil
import signal
import sys
import threading
from collections.abc import Iterator, Sequence

from .. import __version__
from ..core.errors import QuashError, UsageError
from ..core.redact import redact
from ._output import setup_logging

log = logging.getLogger("quash_plugins.cli")

DESCRIPTION = """\
QuASH: Query Augmentation using Semantic Heuristics, for the maps robots already build.
A query is expanded into synonyms and antonyms, embedded with the map's own text
encoder, used to train a classifier, and every voxel, point or pixel is labelled."""

EPILOG = """\
examples:
  quash demo                                   # offline demo on a generated scene
  quash make-scene scene.npz                   # a labelled map to try things on
  quash query scene.npz chair sofa -c demo:quash-taxonomy --out result.npz --rrd result.rrd
  quash expand chair -c demo:quash-taxonomy --json
  quash configs                                # shipped configs, for -c NAME
  quash plugins
Run 'quash COMMAND --help' for the options of each command."""


def _clean(exc: BaseException) -> str:
    """An error message fit for the terminal: credentials redacted, controls escaped."""
    from ..core.types import escape_control

    return escape_control(redact(exc))


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread so that ``finally`` blocks and cleanup run."""


def _raise_terminated(signum, frame) -> None:
    # A second SIGTERM during cleanup must not interrupt the cleanup itself.
    signal.signal(signal.SIGTERM, lambda *_: None)
    raise Terminated()


@contextlib.contextmanager
def _sigterm_as_exception() -> Iterator[None]:
    """Turn SIGTERM into :class:`Terminated` while a command runs (main thread only).

    SIGINT raises KeyboardInterrupt even where a shell started the command in the
    background with SIGINT ignored (``quash demo --serve-web &`` in a script): a user
    who sends it means it. Both handlers are restored after.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    previous_int = signal.getsignal(signal.SIGINT)
    if previous_int in (signal.SIG_IGN, signal.SIG_DFL):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        if previous_int is not None:
            signal.signal(signal.SIGINT, previous_int)


def _commands():
    import quash_plugins.cli as pkg

    mods = []
    for info in pkgutil.iter_modules(pkg.__path__):
        if info.name.startswith("cmd_"):
            mods.append(importlib.import_module(f"{pkg.__name__}.{info.name}"))
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 50), m.NAME))


def _output_options(suppress: bool) -> argparse.ArgumentParser:
    """``-v``, ``-q`` and ``--debug``, accepted before and after the subcommand.

    The subcommand's copies default to ``SUPPRESS``: argparse copies a subparser's
    defaults over the main parser's values, so ``quash --debug query ...`` would
    otherwise lose the ``--debug`` given before the subcommand.
    """
    common = argparse.ArgumentParser(add_help=False)
    g = common.add_argument_group("output")
    none: dict = {"default": argparse.SUPPRESS} if suppress else {}
    g.add_argument(
        "-v",
        "--verbose",
        action="count",
        help="More log output (-vv: most).",
        **(none or {"default": 0}),
    )
    g.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help=(
            "Warnings, errors and the command's result; no progress, INFO or 'wrote' "
            "lines (the Hugging Face libraries': errors only)."
        ),
        **none,
    )
    g.add_argument("--debug", action="store_true", help="Show tracebacks on errors.", **none)
    return common


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Descriptions and epilogs refilled to the terminal's width, their layout kept.

    The texts are written wrapped at some width in the source; printed as they are, an
    80-column terminal folds each of their lines mid-word. Here a paragraph (lines
    between blank lines) is refilled to the width argparse uses for the options; a line
    that starts with a space (an example command, a continued item) is kept as it is,
    and one that starts with ``- `` begins an item of its own, refilled with a hanging
    indent.
    """

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        import textwrap

        out: list[str] = []
        para: list[str] = []

        def flush() -> None:
            if para:
                first = para[0]
                hang = "  " if first.startswith("- ") else ""
                out.append(
                    textwrap.fill(
                        " ".join(ln.strip() for ln in para),
                        width,
                        initial_indent=indent,
                        subsequent_indent=indent + hang,
                        break_long_words=False,
                        break_on_hyphens=False,
                    )
                )
                para.clear()

        for line in text.splitlines():
            if not line.strip():
                flush()
                out.append("")
            elif line[0].isspace():
                flush()
                out.append(indent + line)
            else:
                if line.startswith("- "):
                    flush()
                para.append(line)
        flush()
        return "\n".join(out)


def build_parser() -> argparse.ArgumentParser:
    common = _output_options(suppress=False)
    common_sub = _output_options(suppress=True)

    parser = argparse.ArgumentParser(
        prog="quash",
        description=DESCRIPTION,
        epilog=EPILOG,
        parents=[common],
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"quash-plugins {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _commands():
        p = sub.add_parser(
            mod.NAME,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            parents=[common_sub],
            formatter_class=HelpFormatter,
            epilog=getattr(mod, "EPILOG", None),
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def subcommand_parsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """``{name: parser}`` of ``parser``'s subcommands (``{}`` when it has none)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _refuse_unknown(parser: argparse.ArgumentParser, command: str | None, extra: list[str]):
    """An argument no parser took: the subcommand's usage and error (argparse gives the
    top-level ones), with the nearest option of that subcommand when one is close."""
    from ..core.errors import closest

    target = subcommand_parsers(parser).get(command, parser) if command else parser
    options = [o for a in target._actions for o in a.option_strings if o.startswith("--")]
    hints = []
    for arg in extra:
        if arg.startswith("--"):
            close = closest(arg.split("=", 1)[0], options, cutoff=0.75)
            if close:
                hints.append(f"{arg.split('=', 1)[0]}: did you mean {close}?")
    help_hint = f"'quash {command} --help'" if command else "'quash --help'"
    target.error(
        f"unrecognized arguments: {' '.join(extra)}"
        + (f" ({'; '.join(hints)})" if hints else "")
        + f"; {help_hint} lists the options."
    )


def _refuse_empty(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """An option or argument given as an empty string (``--rrd "$UNSET"``, ``--out=``):
    argparse takes it, and the command would run as if it had not been given, writing
    nothing and saying nothing. Refused with the subcommand's usage, naming it."""
    target = subcommand_parsers(parser).get(args.command, parser)
    for action in target._actions:
        if action.nargs == 0 or getattr(args, action.dest, None) != "":
            continue
        name = "/".join(action.option_strings) or action.metavar or action.dest
        what = action.metavar or action.dest.upper()
        leave = ", or leave the option out" if action.option_strings else ""
        target.error(
            f"argument {name}: an empty value (an unset shell variable?): give {what}{leave}."
        )


@contextlib.contextmanager
def _dask_clients_closed() -> Iterator[None]:
    """Close the Dask clients a command started (``--backend dask``) when it ends;
    quietly after Ctrl-C or SIGTERM, so that the command's one line is all it says."""
    interrupted = False
    try:
        yield
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        started = sys.modules.get("quash_plugins.engine.dask_client")
        if started is not None:
            started.close_started_clients(quiet=interrupted)


#: The negative axes ``--up`` takes, which argparse would read as options of their own.
_NEGATIVE_AXES = ("-x", "-y", "-z")


def _join_negative_axes(argv: Sequence[str]) -> list[str]:
    """``--up -y`` as ``--up=-y``: argparse reads a value that starts with ``-`` as an
    option ('expected one argument'), and no quash option is named ``-x``, ``-y`` or
    ``-z``. Nothing after ``--`` is touched."""
    out: list[str] = []
    args = list(argv)
    i = 0
    while i < len(args):
        if args[i] == "--":
            out += args[i:]
            break
        if args[i] == "--up" and i + 1 < len(args) and args[i + 1] in _NEGATIVE_AXES:
            out.append(f"--up={args[i + 1]}")
            i += 2
            continue
        out.append(args[i])
        i += 1
    return out


def main(argv: Sequence[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # Ctrl-C before the command runs (imports, the parser)
        print("interrupted", file=sys.stderr)
        return 130


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    argv = _join_negative_axes(sys.argv[1:] if argv is None else argv)
    args, extra = parser.parse_known_args(argv)
    if extra:
        _refuse_unknown(parser, getattr(args, "command", None), extra)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    _refuse_empty(parser, args)
    setup_logging(args.verbose, args.quiet)
    try:
        with _sigterm_as_exception(), _dask_clients_closed():
            return int(args._run(args) or 0)
    except Terminated:
        print("terminated", file=sys.stderr)
        return 143
    except UsageError as exc:
        if args.debug:
            raise
        print(f"quash {args.command}: error: {_clean(exc)}", file=sys.stderr)
        return 2
    except QuashError as exc:
        if args.debug:
            raise
        print(f"quash {args.command}: error: {_clean(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # The reader stopped early (``quash plugins | head``): not an error to report.
        # Point stdout at /dev/null so the interpreter's final flush does not fail again.
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for a reader that hung up
    except Exception as exc:
        if args.debug:
            raise
        print(
            f"quash {args.command}: unexpected error: {type(exc).__name__}: {_clean(exc)}\n"
            "Re-run with --debug for the traceback.",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
