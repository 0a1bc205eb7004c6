"""quash expand without --map on a config with map_negatives says that the mined
negatives are missing (docs/quickstart.md: see what a heuristic makes of a query before
you run it; quash query would add them)."""

from __future__ import annotations

import pytest

from quash_plugins.cli.main import main


@pytest.mark.parametrize("mined", [True, False])
def test_expand_without_a_map_says_map_negatives_need_one(tiny_world, monkeypatch, capsys, mined):
    config = tiny_world["dir"] / "mined.yaml"
    config.write_text(
        tiny_world["config"].read_text() + ("map_negatives: {n: 5}\n" if mined else "")
    )
    monkeypatch.chdir(tiny_world["dir"])
    assert main(["expand", "chair", "-c", config.name]) == 0
    captured = capsys.readouterr()
    assert "negatives (3): other, background, nothing" in captured.out
    said = "map_negatives" in captured.err and "--map MAP" in captured.err
    assert said == mined, captured.err
