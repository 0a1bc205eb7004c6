"""``quash demo --help`` and ``quash make-scene --help`` fit an 80-column terminal.

Their descriptions and examples were wrapped at 88 columns, so an 80-column terminal
folded every line of them mid-word."""

from __future__ import annotations

import pytest

from quash_plugins.cli.main import main


def _help(name: str, capsys, monkeypatch) -> str:
    monkeypatch.setenv("COLUMNS", "80")
    with pytest.raises(SystemExit):
        main([name, "--help"])
    return capsys.readouterr().out


@pytest.mark.parametrize("name", ["demo", "make-scene"])
def test_help_fits_80_columns(name, capsys, monkeypatch):
    out = _help(name, capsys, monkeypatch)
    # the Rerun group's paragraph is wrapped by _viewer_opts, for every command alike
    lines = out.splitlines()
    if "Rerun viewer:" in out:
        start = lines.index("Rerun viewer:")
        end = next(i for i in range(start, len(lines)) if "--rrd FILE.rrd" in lines[i])
        lines = lines[:start] + lines[end:]
    wide = [line for line in lines if len(line) > 80]
    assert not wide, "\n".join(wide)


@pytest.mark.parametrize("name", ["demo", "make-scene"])
def test_wrapped_description_keeps_every_word(name, capsys, monkeypatch):
    """Rewrapping kept the text: the description is in the help, word for word."""
    from quash_plugins.cli import cmd_demo, cmd_make_scene

    mod = {"demo": cmd_demo, "make-scene": cmd_make_scene}[name]
    out = " ".join(_help(name, capsys, monkeypatch).split())
    assert " ".join(mod.DESCRIPTION.split()) in out
