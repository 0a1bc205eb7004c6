"""Every ``quash`` help fits an 80-column terminal, and its texts keep every word.

The descriptions, epilogs and group texts are written wrapped at some width in the
source; printed as they were, an 80-column terminal folded each of their lines
mid-word. The help formatter refills their paragraphs to the terminal's width and keeps
example lines (indented) as they are."""

from __future__ import annotations

import argparse

import pytest

from quash_plugins.cli.main import HelpFormatter, _commands, main

COMMANDS = [m.NAME for m in _commands()]


def _help(argv: list[str], capsys, monkeypatch, columns: int = 80) -> str:
    monkeypatch.setenv("COLUMNS", str(columns))
    with pytest.raises(SystemExit):
        main([*argv, "--help"])
    return capsys.readouterr().out


def _example(line: str) -> bool:
    """An example command of an epilog, its continuation or its comment column: kept
    as written, so that it can be copied."""
    text = line.lstrip()
    return line.startswith("  ") and text.startswith(("quash ", "--", "#", ".venv/"))


@pytest.mark.parametrize("argv", [[], *[[c] for c in COMMANDS]])
def test_help_fits_80_columns(argv, capsys, monkeypatch):
    lines = _help(argv, capsys, monkeypatch).splitlines()
    wide = [line for line in lines if len(line) > 80 and not _example(line)]
    assert not wide, "\n".join(wide)


@pytest.mark.parametrize("name", COMMANDS)
def test_refilled_description_keeps_every_word(name, capsys, monkeypatch):
    """Refilling kept the text: the description is in the help, word for word, at a
    narrow and at a wide terminal."""
    mod = next(m for m in _commands() if name == m.NAME)
    text = " ".join(getattr(mod, "DESCRIPTION", mod.HELP).split())
    for columns in (60, 160):
        out = " ".join(_help([name], capsys, monkeypatch, columns).split())
        assert text in out


def test_the_formatter_keeps_examples_and_items():
    fmt = HelpFormatter("quash")
    text = (
        "A paragraph written wrapped at some\nwidth in the source.\n\n"
        "examples:\n  quash query map.npz chair --out a-very-long-name-that-stays.npz\n"
        "- an item that is long enough to be wrapped onto a second line here\n"
        "- another"
    )
    out = fmt._fill_text(text, 30, "").splitlines()
    assert out[0] == "A paragraph written wrapped at"
    assert out[1] == "some width in the source."
    assert out[2] == ""
    assert "  quash query map.npz chair --out a-very-long-name-that-stays.npz" in out
    item = out.index("- an item that is long enough")
    assert out[item + 1].startswith("  to be wrapped")  # a hanging indent
    assert out[-1] == "- another"
    assert isinstance(fmt, argparse.RawDescriptionHelpFormatter)
