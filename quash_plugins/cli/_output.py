"""Console output of the subcommands: logging, JSON and rich tables.

Tables printed to the terminal are rich tables sized to its width: headers and text
cells wrap at spaces only, numbers never fold, a row's name and a label stay on one line, and a table whose columns cannot fit is
shown in parts (each with the first column) under a note. A Markdown image line is
printed as ``plot: PATH``. Markdown is only what the commands write to files.
"""

from __future__ import annotations

import contextlib
import json
import logging
import re
import sys
from collections.abc import Iterator
from typing import Any

log = logging.getLogger("quash_plugins.cli")


def setup_logging(verbose: int, quiet: bool) -> None:
    """Route ``quash_plugins`` logging to stderr, credentials redacted and control
    characters escaped: through rich on a terminal, as plain one-line records
    (``WARNING  message``) otherwise, so logs in files never wrap."""
    from ..core import progress as _progress
    from ..core.redact import RedactingFilter

    level = logging.WARNING if quiet else (logging.DEBUG if verbose else logging.INFO)
    _progress.QUIET = quiet
    handler: logging.Handler
    if sys.stderr.isatty():
        from rich.console import Console
        from rich.logging import RichHandler

        handler = RichHandler(
            console=Console(stderr=True),
            show_time=False,
            show_path=verbose > 1,
            markup=False,
            rich_tracebacks=False,
        )
    else:
        handler = logging.StreamHandler(sys.stderr)
        fmt = "%(levelname)-8s %(message)s" + (" (%(name)s)" if verbose > 1 else "")
        handler.setFormatter(logging.Formatter(fmt))
    handler.addFilter(RedactingFilter())
    handler.addFilter(_EscapeControls())
    root = logging.getLogger("quash_plugins")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False
    _format_own_warnings()


def _format_own_warnings() -> None:
    """Print this package's warnings (an empty map's :class:`EmptyMapWarning`...) as log
    lines are printed, ``WARNING  message``, not as Python's default
    ``/path/to/quash_plugins/cli/cmd_query.py:108: EmptyMapWarning: message``, which
    points at our code rather than at the user's input. Other packages' warnings, and
    code that records warnings (``warnings.catch_warnings(record=True)``), are as before.
    """
    import warnings

    default = getattr(warnings.formatwarning, "_quash_default", warnings.formatwarning)

    def formatwarning(message, category, filename, lineno, line=None):
        if getattr(category, "__module__", "").startswith("quash_plugins"):
            return f"WARNING  {message}\n"
        return default(message, category, filename, lineno, line)

    formatwarning._quash_default = default  # type: ignore[attr-defined]
    warnings.formatwarning = formatwarning


class _Once(logging.Filter):
    """Drops a log record whose level and message were already shown."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: set[tuple[int, str]] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.levelno, record.getMessage())
        if key in self.seen:
            return False
        self.seen.add(key)
        return True


@contextlib.contextmanager
def each_log_line_once() -> Iterator[None]:
    """Within the block, each distinct log line is shown once: several configs answering
    the same queries (quash eval, quash bench) log the same resolution of a query once
    per config, word for word."""
    handlers = list(logging.getLogger("quash_plugins").handlers)
    once = _Once()
    for h in handlers:
        h.addFilter(once)
    try:
        yield
    finally:
        for h in handlers:
            h.removeFilter(once)


class _EscapeControls(logging.Filter):
    """Log lines cannot drive the terminal: control characters are escaped."""

    def filter(self, record: logging.LogRecord) -> bool:
        from ..core.types import escape_control

        try:
            message = record.getMessage()
        except Exception:  # noqa: BLE001 - a bad format string is logging's business
            return True
        clean = escape_control(message)
        if clean != message:
            record.msg, record.args = clean, None
        return True


def say_done(args: Any, text: str) -> None:
    """Print ``text``, a line that says what a command did rather than what it found
    (``wrote FILE``, ``table fair: done``), on stderr, unless ``--quiet``
    (``args.quiet``). Status goes to stderr, as the recording's ``wrote FILE.rrd`` does
    and logging does; stdout holds the command's own result (the table of ``quash
    eval``, the answers of ``quash query``, printed on the command's console whatever
    ``--quiet`` says), so ``quash query ... > answers.txt`` holds only answers. ``text``
    is printed as it is, on one line: control characters escaped, nothing read as
    markup."""
    if not getattr(args, "quiet", False):
        print(safe_text(text, markup=False), file=sys.stderr, flush=True)


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, ensure_ascii=False, default=str)
    sys.stdout.write("\n")


def safe_text(value: Any, markup: bool = True) -> str:
    """``value`` as text that cannot drive the terminal: control characters escaped
    (``\\x1b``), and rich markup escaped unless ``markup`` is False (for
    ``print(..., markup=False)``). For every string that came from a user, a map or a
    server: queries, label names, heuristic outputs, plugin metadata."""
    from rich.markup import escape

    from ..core.types import escape_control

    text = escape_control(str(value))
    return escape(text) if markup else text


def console():
    """A rich console on stdout, as wide as the terminal (``COLUMNS`` in a pipe)."""
    from rich.console import Console

    return Console(highlight=False)


_CELL_MARKUP = re.compile(r"\*\*(.+?)\*\*|`([^`]+)`")


def _cell(text: str) -> Any:
    """A table cell of our Markdown (``**bold**`` and ```code```) as rich Text."""
    from rich.text import Text

    out = Text()
    pos = 0
    for m in _CELL_MARKUP.finditer(text):
        out.append(text[pos : m.start()])
        if m.group(1) is not None:
            out.append(m.group(1), style="bold")
        else:
            out.append(m.group(2), style="cyan")
        pos = m.end()
    out.append(text[pos:])
    return out


def _split_row(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _blocks(md: str) -> Iterator[tuple[str, list[str]]]:
    """``("table", lines)`` for each pipe table, ``("text", [line])`` for other lines."""
    lines = md.splitlines()
    i = 0
    while i < len(lines):
        line = lines[i]
        is_table = (
            line.lstrip().startswith("|")
            and i + 1 < len(lines)
            and re.fullmatch(r"\s*\|?\s*:?-{3,}:?\s*(\|\s*:?-{3,}:?\s*)*\|?\s*", lines[i + 1])
        )
        if is_table:
            j = i + 2
            while j < len(lines) and lines[j].lstrip().startswith("|"):
                j += 1
            yield "table", lines[i:j]
            i = j
        else:
            yield "text", [line]
            i += 1


#: Headers of text columns that, as the first column, name something and are kept on one
#: line: a ground-truth label ("tv monitor", "chest of drawers") broken over two lines reads
#: as two labels.
_WHOLE = ("label",)


def _whole(i: int, header: list[str]) -> bool:
    """Whether column ``i`` keeps each cell on one line: the first column (it names the
    row: a query, a method) and a column of :data:`_WHOLE` (a label)."""
    return i == 0 or _cell(header[i]).plain.strip().casefold() in _WHOLE


#: Spaces between two columns of a terminal table (a one-space divider plus padding),
#: from the most generous to the tightest.
_GAPS = (3, 2, 1)


def _widths(
    header: list[str], body: list[list[str]], align: list[str], whole: set[int] | None = None
) -> list[tuple]:
    """Per column ``(lo, hi, right)``: the narrowest width that breaks no word of its
    header and no cell (a number, the first column or a label is never wrapped; other
    text wraps at spaces), the width that shows every cell and the header on one line, and whether
    it is right-aligned (``---:`` in the Markdown). ``whole``: the columns kept on one
    line (default: those of :func:`_whole`)."""
    from rich.cells import cell_len

    if whole is None:
        whole = {i for i in range(len(header)) if _whole(i, header)}

    out = []
    for i, name in enumerate(header):
        spec = align[i] if i < len(align) else ""
        right = spec.endswith(":") and not spec.startswith(":")
        cells = [_cell(r[i]).plain if i < len(r) else "" for r in body]
        head = _cell(name).plain
        full = max([cell_len(c) for c in cells], default=0)
        words = [cell_len(w) for c in cells for w in c.split()]
        head_words = max((cell_len(w) for w in head.split()), default=0)
        if i in whole:  # names the row, or a label: on one line, header included
            lo = max(full, cell_len(head))
        elif right:  # a number is never folded
            lo = max(full, head_words)
        else:
            lo = max(max(words, default=0), head_words)
        out.append((lo, max(full, cell_len(head), lo), right))
    return out


def _layout(cols: list[tuple], width: int | None) -> tuple[int, list[int] | None] | None:
    """``(gap, widths)`` for columns that fit in ``width``: ``widths`` None when every
    header and cell fits on one line (rich sizes the columns), else fixed widths between
    each column's ``lo`` and ``hi``; None when even the narrowest do not fit."""
    gaps = len(cols) - 1
    if width is None:
        return _GAPS[0], None
    for gap in _GAPS[:2]:
        if sum(hi for _, hi, _ in cols) + gap * gaps <= width:
            return gap, None
    for gap in _GAPS[1:]:
        spare = width - sum(lo for lo, _, _ in cols) - gap * gaps
        if spare >= 0:
            widths = [lo for lo, _, _ in cols]
            want = [hi - lo for lo, hi, _ in cols]
            total = sum(want)
            for k, w in enumerate(want):  # the spare columns, in proportion to the want
                widths[k] += spare * w // total if total else 0
            return gap, widths
    return None


def _groups(cols: list[tuple], width: int) -> list[list[int]]:
    """Column indices of the parts of a table too wide for ``width``: each part is the
    first column and as many of the next ones as fit, with the tightest gap."""
    parts: list[list[int]] = []
    part, used = [0], cols[0][0]
    for k in range(1, len(cols)):
        if len(part) > 1 and used + _GAPS[-1] + cols[k][0] > width:
            parts.append(part)
            part, used = [0], cols[0][0]
        part.append(k)
        used += _GAPS[-1] + cols[k][0]
    parts.append(part)
    return parts


def markdown_table(lines: list[str], width: int | None = None) -> Any:
    """A rich renderable for the lines of one Markdown pipe table, at most ``width`` wide.

    Columns aligned ``---:`` in the Markdown are right-aligned, and a number is never
    folded. A header wraps only at its spaces, and a text cell too; the first column,
    which names the row, and a ``label`` column (a query's ground-truth label) stay on
    one line (a label too long for that beside the first column wraps at its spaces). When the columns do not fit even so (many
    configs side by side on a narrow terminal), the table is printed in parts, each with
    the first column and as many others as fit, under a note saying so.
    """
    from rich import box
    from rich.console import Group
    from rich.table import Table
    from rich.text import Text

    header, align, *body = (_split_row(ln) for ln in lines)
    whole = {i for i in range(len(header)) if _whole(i, header)}
    cols = _widths(header, body, align, whole)
    if width is not None:
        # a label that cannot stand on one line beside the first column wraps at its
        # spaces, as other text does: cut, 'chest of drawers' read 'chest of drawer'
        gap = _GAPS[-1]
        tight = {i for i in whole - {0} if cols[0][0] + gap + cols[i][0] > width}
        if tight:
            whole -= tight
            cols = _widths(header, body, align, whole)
    layout = _layout(cols, width)
    if layout is None and width is not None and len(header) > 2:
        parts = _groups(cols, width)
        if len(parts) > 1:
            note = Text(
                f"(the table is too wide for {width} columns: it is shown in {len(parts)} "
                "parts, each with the first column)",
                style="dim",
            )
            tables: list[Any] = [note]
            for n, part in enumerate(parts):
                sub = [
                    "| " + " | ".join(r[k] if k < len(r) else "" for k in part) + " |"
                    for r in (header, *body)
                ]
                sub.insert(
                    1, "|" + "|".join(align[k] if k < len(align) else "---" for k in part) + "|"
                )
                tables += [Text("")] if n else []
                tables.append(markdown_table(sub, width))
            return Group(*tables)
    gap, fixed = layout if layout is not None else (_GAPS[-1], None)
    pad = {3: (0, 1), 2: (0, 0, 0, 1), 1: (0, 0)}[gap]
    table = Table(box=box.SIMPLE_HEAD, show_edge=False, pad_edge=False, padding=pad)
    for i, name in enumerate(header):
        table.add_column(
            _cell(name),
            justify="right" if cols[i][2] else "left",
            overflow="fold",
            no_wrap=i in whole,
            width=fixed[i] if fixed else None,
            min_width=cols[i][0] if cols[i][2] or i in whole else None,
        )
    for row in body:
        table.add_row(*[_cell(c) for c in row[: len(header)]])
    return table


def _split_given(lines: list[str]) -> list[list[str]]:
    """A table with a ``given`` column (what each method was given: long text) as two
    tables on the terminal: the numbers, then ``method | given``, so that neither folds."""
    header = _split_row(lines[0])
    if "given" not in header[1:]:
        return [lines]
    k = header.index("given")
    rows = [_split_row(ln) for ln in lines]

    def join(cells: list[str]) -> str:
        return "| " + " | ".join(cells) + " |"

    numbers = [join(r[:k] + r[k + 1 :]) for r in rows]
    given = [join([r[0], r[k]]) for r in rows]
    return [numbers, given]


#: A Markdown image line, ``![title](path)``: a plot a report links to.
_IMAGE = re.compile(r"\s*!\[[^\]]*\]\((?P<path>[^)]*)\)\s*")


def print_markdown(out: Any, md: str, base: Any = None) -> None:
    """Print our Markdown reports on ``out``: pipe tables as rich tables sized to the
    terminal, ``#`` headings in bold, an image line ``![title](fair.png)`` as
    ``plot: PATH`` (its path joined to ``base``, the report's folder), every other line
    as it is (never hard-wrapped). Control characters are escaped and nothing is read as
    rich markup."""
    from pathlib import Path

    from rich.text import Text

    from ..core.types import escape_control

    md = escape_control(md)  # names from maps and servers cannot drive the terminal
    for kind, lines in _blocks(md):
        if kind == "table":
            for n, part in enumerate(_split_given(lines)):
                if n:
                    out.print()
                out.print(markdown_table(part, out.width))
            continue
        line = lines[0]
        image = _IMAGE.fullmatch(line)
        if image:
            path = image.group("path")
            path = str(Path(base) / path) if base is not None and path else path
            out.print(Text(f"plot: {path}"), soft_wrap=True)
            continue
        heading = re.match(r"#+\s+(.*)", line)
        if heading:
            out.print(Text(heading.group(1), style="bold"), soft_wrap=True)
        else:
            out.print(_cell(line), soft_wrap=True)


#: Pipeline stages in order; those in SHARED are done once for all the queries of a call.
STAGES = ("read", "expand", "encode", "fit", "classify", "postprocess", "refine", "reclassify")
SHARED = ("read", "encode", "classify", "reclassify")


def timings_table(results: list[Any], max_columns: int = 6, width: int = 80) -> Any:
    """Per-query stage times in ms, with the stages shared by the queries of one call
    marked ``*`` (each query shows its equal share) and their whole cost in a note below.

    Up to ``max_columns`` queries are columns (one row per stage, narrow enough for any
    terminal); more queries are rows, one column per stage, fitted to a console of
    ``width`` columns (headers and queries fold; numbers are never cut).
    """
    from rich import box
    from rich.table import Table
    from rich.text import Text

    from ..core.types import escape_control

    stages = [s for s in (*STAGES, "presence", "instances") if any(s in r.timings for r in results)]
    label = {s: f"{s}*" if s in SHARED else s for s in stages}
    table = Table(
        title="time per stage (ms)",
        title_justify="left",
        box=box.SIMPLE_HEAD,
        collapse_padding=True,
        pad_edge=False,
    )

    def ms(r: Any, s: str) -> str:
        if s not in r.timings:
            return "-"
        value = 1000 * r.timings[s]
        return f"{value:.0f}" if value >= 100 else f"{value:.1f}"  # 3 significant digits

    if len(results) <= max_columns:
        table.add_column("stage", no_wrap=True)
        for r in results:
            table.add_column(Text(escape_control(r.query)), justify="right", overflow="fold")
        for s in stages:
            table.add_row(label[s], *[ms(r, s) for r in results])
    else:
        # The numbers are never broken (a console of 80 columns, or a pipe, folded "24.9"
        # over three lines): each stage's column is as wide as its numbers, its header
        # folds, and a long query folds.
        table.add_column("query", overflow="fold", min_width=8)
        numbers = {s: max(len(ms(r, s)) for r in results) for s in stages}
        whole = sum(max(numbers[s], len(label[s])) + 1 for s in stages) + 12 <= width
        for s in stages:
            # a set width, never cut: the header's where they all fit, else the numbers'
            fit = max(numbers[s], len(label[s]) if whole else 5)
            table.add_column(label[s], justify="right", overflow="fold", width=fit)
        for r in results:
            table.add_row(Text(escape_control(r.query)), *[ms(r, s) for s in stages])
    shared = []
    for s in stages:
        if s in SHARED:
            n = sum(1 for r in results if s in r.timings)
            total = 1000 * sum(r.timings.get(s, 0.0) for r in results)
            shared.append(f"{s} {total:.1f} ms for {n} quer{'y' if n == 1 else 'ies'}")
    if not shared:
        return table
    from rich.console import Group

    note = "* done once for all the queries, split equally: " + ", ".join(shared)
    return Group(table, Text(note, style="dim"))
