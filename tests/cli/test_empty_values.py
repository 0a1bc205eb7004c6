"""An option or argument given as an empty string (``--rrd "$UNSET"``) is refused by
name: argparse accepts it, and the command used to run as if it had not been given
(``--rrd=``, ``--out=``, ``--connect=``, ``eval --json=``: exit 0, nothing written,
nothing said)."""

from __future__ import annotations

import pytest

from quash_plugins.cli.main import main


@pytest.mark.parametrize(
    ("command", "option", "leave"),
    [
        (["query", "MAP", "chair"], ["--rrd="], True),
        (["query", "MAP", "chair"], ["--out", ""], True),
        (["query", "MAP", "chair"], ["--connect="], True),
        (["eval", "MAP"], ["--json="], True),
        (["eval", "MAP"], ["--plot", ""], True),
        (["demo"], ["--out="], True),
        (["convert", "MAP"], [""], False),
        (["query", "", "chair"], [], False),
    ],
)
def test_an_empty_value_is_refused_before_any_work(
    tiny_world, tmp_path, monkeypatch, capsys, command, option, leave
):
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    argv = [str(tiny_world["map"]) if a == "MAP" else a for a in command] + option
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "an empty value" in err
    assert ("leave the option out" in err) == leave
    assert list(here.iterdir()) == []  # nothing written (demo's --out= is no ./quash-demo)
