"""The comparison commands that README.md and docs/quickstart.md show measure the empty
answer: each method's absence score, the promise to return nothing for an object that is
not there, comes out as a number, not n/a (with `--all-labels` no query was of an absent
object)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _comparisons() -> list[tuple[str, str]]:
    """``(doc, command)`` for each ``quash eval`` of the docs that compares configs (two
    or more ``-c``), a command continued over lines with a backslash read as one."""
    out = []
    for doc in ("README.md", "docs/quickstart.md"):
        text = (ROOT / doc).read_text(encoding="utf-8").replace("\\\n", " ")
        for line in text.splitlines():
            cmd = line.split("#")[0].strip()
            if cmd.startswith("quash eval ") and len(re.findall(r"(?:^|\s)-c\s", cmd)) >= 2:
                out.append((doc, cmd))
    return out


def test_the_docs_show_a_comparison():
    assert {doc for doc, _ in _comparisons()} == {"README.md", "docs/quickstart.md"}


@pytest.mark.slow
@pytest.mark.parametrize(("doc", "command"), _comparisons())
def test_a_documented_comparison_scores_absence(doc, command, minilm_scene, tmp_path, monkeypatch):
    from quash_plugins.cli.main import main

    for f in minilm_scene.parent.iterdir():  # the map and the files make-scene wrote
        shutil.copy(f, tmp_path / f.name)
    monkeypatch.chdir(tmp_path)
    args = shlex.split(command)[1:]
    assert args[1] == "scene.npz", command
    assert main([*args, "--json", "report.json"]) == 0, (doc, command)
    report = json.loads(Path("report.json").read_text())
    assert report["provenance"]["absent"], (doc, command)
    for c in report["configs"]:
        ab = c["absence"]
        assert ab["score"] is not None and set(ab["per_query"]) == set(
            report["provenance"]["absent"]
        ), (doc, command, c["name"])
