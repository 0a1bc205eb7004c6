"""``quash cache info|clear --dir DIR`` show and clear only what DIR holds."""

from __future__ import annotations

import json

import numpy as np

from quash_plugins.cli.main import main
from quash_plugins.engine.cache import TextEmbeddingCache
from quash_plugins.heuristics._llm_cache import cache_file_name, default_cache_dir


def _llm_set(folder, model):
    folder.mkdir(parents=True, exist_ok=True)
    key = {"model": model, "endpoint": "http://localhost:1/v1", "query": "chair"}
    (folder / cache_file_name(key)).write_text(json.dumps({"key": key}), encoding="utf-8")


def test_info_dir_lists_only_that_folder(tmp_path, capsys):
    _llm_set(default_cache_dir(), "default-model")  # in the default LLM folder, not in DIR
    other = tmp_path / "elsewhere"
    TextEmbeddingCache(other).store("fp-other", {"a": np.ones(3, np.float32)})
    capsys.readouterr()

    assert main(["cache", "info", "--dir", str(other)]) == 0
    text = capsys.readouterr().out
    assert "fp-other" in text
    assert "default-model" not in text and str(default_cache_dir()) not in text

    assert main(["cache", "info", "--json", "--dir", str(other)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["directory"] == str(other) and info["entries"] == 1
    assert "llm" not in info

    # without --dir the default LLM folder is still listed
    assert main(["cache", "info", "--json"]) == 0
    llm = json.loads(capsys.readouterr().out)["llm"]
    assert llm["directory"] == str(default_cache_dir()) and llm["sets"] == 1

    # clear --dir says nothing about the default folder's query sets, and keeps them
    assert main(["cache", "clear", "--dir", str(other)]) == 0
    text = capsys.readouterr().out
    assert str(other) in text and "LLM" not in text
    assert main(["cache", "info", "--llm", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sets"] == 1


def test_info_llm_dir_lists_only_that_folder(tmp_path, capsys):
    _llm_set(default_cache_dir(), "default-model")
    own = tmp_path / "llm-cache"
    _llm_set(own, "own-model")
    capsys.readouterr()
    assert main(["cache", "info", "--llm", "--dir", str(own)]) == 0
    text = capsys.readouterr().out
    assert "own-model" in text and "default-model" not in text
    assert main(["cache", "info", "--llm", "--json", "--dir", str(own)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["directory"] == str(own) and [m["model"] for m in info["models"]] == ["own-model"]


def test_cache_help_names_every_command_that_takes_no_cache():
    """`quash cache --help` says which commands turn the cache off with --no-cache: all
    of them (it once named only query and expand)."""
    import re

    from quash_plugins.cli import cmd_cache
    from quash_plugins.cli.main import build_parser, subcommand_parsers

    takes = sorted(
        name
        for name, sub in subcommand_parsers(build_parser()).items()
        if any("--no-cache" in a.option_strings for a in sub._actions)
    )
    said = re.search(r"--no-cache \(([^)]*)\)", " ".join(cmd_cache.DESCRIPTION.split()))
    assert takes and said is not None
    assert sorted(w.strip() for w in said.group(1).split(",")) == takes
