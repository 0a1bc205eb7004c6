"""What the docs show a command printing is what it prints: the `quash expand` blocks of
docs/heuristics.md and the keys of `quash eval --json` in docs/evaluation.md."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
import yaml

from quash_plugins.cli.main import main

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _blocks(doc: str, lang: str) -> list[str]:
    text = (DOCS / doc).read_text(encoding="utf-8")
    return re.findall(rf"^```{lang}\n(.*?)^```", text, flags=re.S | re.M)


def _keys(obj, path: str = "") -> set[str]:
    """Every key path of a JSON value; the entries of a ``per_query`` or ``queries``
    mapping (keyed by query text) and of a list count as one, ``*``."""
    if isinstance(obj, list):
        return set().union(*(_keys(v, path + "[]") for v in obj if isinstance(v, dict | list)))
    if not isinstance(obj, dict):
        return set()
    out = set()
    for k, v in obj.items():
        k = "*" if path.endswith(("per_query", "queries")) else k
        out |= {f"{path}.{k}"} | _keys(v, f"{path}.{k}")
    return out


def test_eval_json_has_the_keys_the_docs_show(minilm_scene, tmp_path, monkeypatch, capsys):
    """docs/evaluation.md's `--json` example holds every key the report has, and no other."""
    (shown,) = _blocks("evaluation.md", "json")
    present = yaml.safe_load(minilm_scene.with_suffix(".queries.yaml").read_text())["present"]
    monkeypatch.chdir(minilm_scene.parent)
    args = ["-q", "eval", minilm_scene.name, "-c", "demo:quash-labels"]
    args += ["--queries", f"a {present[0]}={present[0]}", "--absent", "piano"]
    assert main([*args, "--json", str(tmp_path / "r.json")]) == 0
    ran = json.loads((tmp_path / "r.json").read_text())
    assert _keys(json.loads(shown)) == _keys(ran), _keys(json.loads(shown)) ^ _keys(ran)


EXPAND = {
    # the block's first line, the config its comment describes
    "$ quash expand chair -c lexicon.yaml": {
        "seed": 1,
        "heuristic": {"name": "lexicon", "n_synonyms": 5, "n_antonyms": 5},
    },
    "$ quash expand chair -c templates.yaml": {"heuristic": {"name": "templates", "mode": "mean"}},
    "$ quash expand chair -c combine.yaml": {
        "heuristic": {
            "name": "combine",
            "synonyms": {"name": "taxonomy", "file": "tax.yaml"},
            "antonyms": {"name": "taxonomy", "file": "tax.yaml"},
        }
    },
}


@pytest.mark.parametrize("first", list(EXPAND))
def test_expand_prints_what_heuristics_md_shows(first, tmp_path, monkeypatch, capsys):
    """Each line the block shows (``...`` elides the rest) is a line of the output, in order."""
    (block,) = [b for b in _blocks("heuristics.md", "console") if b.startswith(first)]
    tax = {"chair": ["armchair", "recliner"], "table": ["desk"], "lamp": ["floor lamp"]}
    (tmp_path / "tax.yaml").write_text(yaml.safe_dump(tax, sort_keys=False))
    config = tmp_path / first.split()[-1]
    config.write_text(yaml.safe_dump({"name": config.stem, "encoder": "minilm", **EXPAND[first]}))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("COLUMNS", "200")  # a line of the docs is one line of the output
    capsys.readouterr()
    assert main(first.split()[2:]) == 0
    printed = iter(capsys.readouterr().out.splitlines())
    for line in block.splitlines()[1:]:
        if line.strip() != "...":
            assert line in printed, (line, block)


def test_expand_shows_a_resolved_query_as_heuristics_md_does(minilm_scene, monkeypatch, capsys):
    """The `heuristic:` line heuristics.md shows for a query resolved to a label."""
    text = (DOCS / "heuristics.md").read_text(encoding="utf-8")
    (shown,) = re.findall(r"^heuristic: taxonomy .*'Bunk-beds'.*$", text, flags=re.M)
    monkeypatch.setenv("COLUMNS", "200")
    args = ["expand", "Bunk-beds", "-c", "demo:quash-labels", "--map", str(minilm_scene)]
    capsys.readouterr()
    assert main(["-q", *args]) == 0
    assert shown in capsys.readouterr().out.splitlines()


def test_expand_shows_a_description_and_its_next_label_as_heuristics_md_does(
    minilm_scene, monkeypatch, capsys
):
    """The `heuristic:` line heuristics.md shows for a description resolved by embedding,
    with the next label; the cosines may differ in the last digits from CPU to CPU."""
    text = (DOCS / "heuristics.md").read_text(encoding="utf-8")
    (shown,) = re.findall(r"^heuristic: taxonomy .*'fabric that covers the window'.*$", text, re.M)
    pattern = re.sub(r"0\\.\d+", r"0\\.\\d+", re.escape(shown))
    monkeypatch.setenv("COLUMNS", "400")
    args = ["expand", "fabric that covers the window", "-c", "demo:quash-labels"]
    capsys.readouterr()
    assert main(["-q", *args, "--map", str(minilm_scene)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert any(re.fullmatch(pattern, line) for line in lines), [
        line for line in lines if line.startswith("heuristic:")
    ]
