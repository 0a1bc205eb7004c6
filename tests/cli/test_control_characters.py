"""Control characters in queries are refused; nothing from outside drives the terminal.

``\\x1b[31m`` in a query reached the result table unescaped, and ``chair\\x00`` gave the
result of ``chair``.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from quash_plugins import Quash
from quash_plugins.cli.main import main
from quash_plugins.core import registry
from quash_plugins.core.errors import QuashError
from quash_plugins.core.interfaces import Heuristic
from quash_plugins.core.types import QuerySet, check_query, escape_control

HOSTILE = ["chair\x1b[31m", "chair\x00", "chair\x00sofa", "\u202echair", "\x9bchair", "ch\x7fair"]


@pytest.mark.parametrize("text", HOSTILE)
def test_check_query_refuses_control_characters_with_their_position(text):
    with pytest.raises(QuashError) as info:
        check_query(text)
    msg = str(info.value)
    assert "control character" in msg and "U+" in msg and "position" in msg
    assert not any(c in msg for c in "\x1b\x00\u202e\x9b\x7f")  # the message itself is safe


def test_white_space_is_still_collapsed():
    assert check_query(" chair\t\nsofa\r") == "chair sofa"  # white space, not control
    assert check_query("café 👨\u200d👩\u200d👧") == "café 👨\u200d👩\u200d👧"


def test_nul_does_not_silently_answer_the_word_before_it(tiny_world):
    q = Quash.from_config(tiny_world["config"])
    assert q.query(tiny_world["map"], "chair").n_matched > 0
    for text in ("chair\x00", "chair\x00sofa"):
        with pytest.raises(QuashError, match="U\\+0000"):
            q.query(tiny_world["map"], text)


def test_cli_refuses_escape_sequences_and_prints_none(tiny_world, capsys):
    rc = main(["query", str(tiny_world["map"]), "chair\x1b[31m", "-c", str(tiny_world["config"])])
    assert rc == 1
    out, err = capsys.readouterr()
    assert "\x1b" not in out + err and "\\x1b[31m" in err


def test_heuristic_outputs_with_control_characters_are_dropped_and_never_printed(capsys):
    class Hostile(Heuristic):
        name = "hostile"

        def expand(self, query, context=None):
            return QuerySet(query, [query, "seat\x1b[2J"], ["lamp", "ta\x00ble"], {})

    registry.register("heuristics", "hostile-test", Hostile)
    try:
        cfg = {
            "encoder": {"name": "table", "table": {"chair": [1, 0], "lamp": [0, 1]}},
            "heuristic": "hostile-test",
            "negatives": [],
            "cache": False,
        }
        qs = Quash.from_config(cfg).expand("chair")
        assert qs.positives == ["chair"] and qs.negatives == ["lamp"]
    finally:
        registry.unregister("heuristics", "hostile-test")


def test_terminal_tables_escape_markup_and_controls(tmp_path, capsys):
    table = {"[red]chair": [1.0, 0.0], "other": [0.0, 1.0], "background": [0, 1], "nothing": [0, 1]}
    cfg = tmp_path / "c.yaml"
    cfg.write_text(json.dumps({"encoder": {"name": "table", "table": table}, "cache": False}))
    np.savez(tmp_path / "m.npz", embeddings=np.eye(2, dtype=np.float32))
    assert main(["query", str(tmp_path / "m.npz"), "[red]chair", "-c", str(cfg)]) == 0
    assert "[red]chair" in capsys.readouterr().out  # shown literally, not as markup

    class Evil(Heuristic):  # a complete plugin: only its name is hostile
        def expand(self, query, context=None):
            raise NotImplementedError

    registry.register("heuristics", "evil\x1b[2Jname", Evil, replace=True)
    try:
        assert main(["plugins", "--kind", "heuristics"]) == 0
        out = capsys.readouterr().out
        assert "\x1b" not in out and "evil\\x1b[2Jname" in out
    finally:
        registry.unregister("heuristics", "evil\x1b[2Jname")


def test_escape_control():
    assert escape_control("a\x1b[31mb\x00\u202e") == "a\\x1b[31mb\\x00\\u202e"
    assert escape_control("line\nnext\ttab") == "line\nnext\ttab"
