"""Every option the docs give a `quash` command is an option of that command.

The commands are read from README.md and docs/*.md: each line of a fenced block that
starts with ``quash`` (or ``$ quash``; a trailing ``\\`` continues it) and each inline
code span starting with ``quash``. The words after ``quash`` that name a subcommand (and
``cache info``) pick the parser; every ``-x``/``--xyz`` after them must be one of its
options, as ``quash SUBCOMMAND --help`` lists them. tests/cli/test_doc_commands.py runs
the commands of README.md and the quickstart; this covers every page, without running.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from quash_plugins.cli.main import build_parser, subcommand_parsers

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _commands(text: str) -> list[tuple[int, str]]:
    """``(line, command)`` of every `quash ...` the page shows."""
    out, lines, block, i = [], text.splitlines(), False, 0
    while i < len(lines):
        s = lines[i].strip()
        if s.startswith("```"):
            block = not block
        elif block and re.match(r"(\$ )?(\.venv/bin/)?quash\s", s):
            cmd, j = s.removeprefix("$ "), i
            while cmd.endswith("\\") and j + 1 < len(lines):
                j += 1
                cmd = cmd[:-1] + " " + lines[j].strip()
            out.append((i + 1, " ".join(cmd.split(" #")[0].split())))
            i = j
        i += 1
    for m in re.finditer(r"(?<!`)`((?:\.venv/bin/)?quash\s[^`]*)`", text):
        out.append((text[: m.start()].count("\n") + 1, " ".join(m.group(1).split())))
    return out


def _unknown_options(cmd: str, parser: argparse.ArgumentParser) -> list[str]:
    """The options of ``cmd`` that its (sub)command does not take."""
    words, path = cmd.split()[1:], ["quash"]
    options = lambda p: {o for a in p._actions for o in a.option_strings}  # noqa: E731
    while words and words[0] in options(parser):  # quash -v query ...
        words = words[1:]
    while words and words[0] in subcommand_parsers(parser):
        parser = subcommand_parsers(parser)[words[0]]
        path.append(words.pop(0))
    known = options(parser)
    flags = [w.strip("[](),;.|").split("=")[0] for w in words]
    return [
        f"{' '.join(path)} {f}"
        for f in flags
        if re.fullmatch(r"--?[a-zA-Z][\w-]*", f) and f not in known
    ]


def test_the_reader_finds_commands_and_their_options():
    text = "```bash\n$ quash -v query m.npz x \\\n  --rrd a.rrd  # c\n```\nrun `quash cache\ninfo --jsn`"
    assert _commands(text) == [
        (2, "quash -v query m.npz x --rrd a.rrd"),
        (5, "quash cache info --jsn"),
    ]
    parser = build_parser()
    assert _unknown_options("quash -v query m.npz x --rrd a.rrd", parser) == []
    assert _unknown_options("quash cache info --jsn", parser) == ["quash cache info --jsn"]


@pytest.mark.parametrize("page", PAGES, ids=[p.name for p in PAGES])
def test_every_option_the_docs_give_a_command_exists(page):
    parser = build_parser()
    found = _commands(page.read_text(encoding="utf-8"))
    bad = [
        f"{page.name}:{line}: {o} (in `{cmd}`)"
        for line, cmd in found
        for o in _unknown_options(cmd, parser)
    ]
    assert not bad, "\n".join(bad)
