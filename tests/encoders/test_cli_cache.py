"""``quash cache info|clear``, ``--no-cache`` and the dimension check, through the CLI."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from quash_plugins.cli.main import main
from quash_plugins.engine.cache import TextEmbeddingCache, default_cache_dir

pytest.importorskip("sentence_transformers")


@pytest.fixture
def minilm_map(minilm, tmp_path):
    """A 384-d NPZ map: 40 items near 'chair', 40 near 'bathtub' (MiniLM's own space)."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(0)
    W = minilm.encode_text(["chair", "bathtub"])
    labels = np.repeat([0, 1], 40)
    E = W[labels] + 0.02 * rng.normal(size=(80, 384))
    E = (E / np.linalg.norm(E, axis=1, keepdims=True)).astype(np.float32)
    pos = rng.uniform(0, 3, size=(80, 3)).astype(np.float32)
    lmap = LatentMap(E, positions=pos, labels=labels, label_names=["chair", "bathtub"])
    return write_npz_map(lmap, tmp_path / "map384.npz"), labels


@pytest.fixture
def counted(monkeypatch):
    """Count the strings that reach MiniLM's model in every MiniLMEncoder."""
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    seen: list[str] = []
    real = MiniLMEncoder.encode_text

    def spy(self, texts):
        seen.extend(texts)
        return real(self, texts)

    monkeypatch.setattr(MiniLMEncoder, "encode_text", spy)
    return seen


def _query(map_path, out, *extra):
    return main(
        [
            "-q",
            "query",
            str(map_path),
            "chair",
            "--adapter",
            "npz",
            "--json",
            "--out",
            str(out),
            "--device",
            "cpu",
            *extra,
        ]
    )


def test_second_query_is_served_from_cache(minilm_map, counted, tmp_path, capsys):
    map_path, labels = minilm_map
    assert _query(map_path, tmp_path / "a.npz") == 0
    assert "chair" in counted
    n_first = len(counted)
    assert TextEmbeddingCache().info()["entries"] == n_first
    assert _query(map_path, tmp_path / "b.npz") == 0
    assert len(counted) == n_first  # nothing reached the model the second time
    with np.load(tmp_path / "a.npz") as a, np.load(tmp_path / "b.npz") as b:
        np.testing.assert_array_equal(a["scores"], b["scores"])
        scores = a["scores"][0]
    # MiniLM is real: every chair item scores above every bathtub item for "chair".
    assert scores[labels == 0].min() > scores[labels == 1].max()


def test_no_cache_flag_neither_reads_nor_writes(minilm_map, counted, tmp_path):
    map_path, _ = minilm_map
    assert _query(map_path, tmp_path / "a.npz", "--no-cache") == 0
    assert not default_cache_dir().exists() or TextEmbeddingCache().info()["entries"] == 0
    n = len(counted)
    assert _query(map_path, tmp_path / "b.npz") == 0  # fills the cache
    assert _query(map_path, tmp_path / "c.npz", "--no-cache") == 0  # must not read it
    assert len(counted) == 3 * n


def test_cache_info_json_and_clear(tmp_path, capsys):
    cache = TextEmbeddingCache()
    cache.store("enc-x", {"chair": np.ones(4, np.float32), "sofa": np.ones(4, np.float32)})
    capsys.readouterr()
    assert main(["cache", "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["directory"] == str(default_cache_dir())
    assert info["entries"] == 2 and info["encoders"][0]["fingerprint"] == "enc-x"
    assert main(["cache", "info"]) == 0
    text = capsys.readouterr().out
    assert "enc-x" in text and str(default_cache_dir()) in text.replace("\n", "")
    assert main(["cache", "clear"]) == 0
    assert "cleared" in capsys.readouterr().out
    assert TextEmbeddingCache().info()["entries"] == 0


def test_cache_dir_option_and_missing_action(tmp_path, capsys):
    other = tmp_path / "elsewhere"
    TextEmbeddingCache(other).store("fp", {"a": np.ones(3, np.float32)})
    assert main(["cache", "info", "--json", "--dir", str(other)]) == 0
    assert json.loads(capsys.readouterr().out)["entries"] == 1
    assert main(["cache", "clear", "--dir", str(other), "--fingerprint", "fp"]) == 0
    assert TextEmbeddingCache(other).info()["entries"] == 0
    assert main(["cache"]) == 2
    assert "info or clear" in capsys.readouterr().err


def test_dimension_mismatch_names_dims_and_preset(tmp_path, capsys):
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    E = np.random.default_rng(1).normal(size=(10, 512)).astype(np.float32)
    path = write_npz_map(LatentMap(E), tmp_path / "lseg512.npz")
    rc = main(["query", str(path), "chair", "--adapter", "npz", "--device", "cpu"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "384" in err and "512" in err and "lseg" in err
    assert "Traceback" not in err


def _console_block(doc: str, command: str) -> list[str]:
    """The lines a ```console block of ``doc`` shows under ``$ command``."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / doc).read_text(encoding="utf-8")
    block = text[text.index(f"$ {command}") :].split("```")[0]
    return block.splitlines()[1:]


def _shape(line: str, directory: str) -> str:
    """A line of `quash cache info` with its folder, numbers and table rules masked."""
    line = line.replace(directory, "DIR")
    line = re.sub(r"\d+(\.\d+)?( [KMG]iB| B)?", "9", line)
    return re.sub(r"[\s─━┏┓┗┛┃│┡┩╇┳┴└┘]+", " ", line).strip()


def test_cache_info_prints_what_the_docs_show(tmp_path, monkeypatch, capsys):
    """docs/encoders.md's `quash cache info`, line by line, up to the folder and the
    numbers (it once left out the table of fingerprints)."""
    monkeypatch.setenv("COLUMNS", "200")
    TextEmbeddingCache().store(
        "sentence-transformers-9e78c519fe6e302d", {"chair": np.ones(4, np.float32)}
    )
    capsys.readouterr()
    assert main(["cache", "info"]) == 0
    root = str(default_cache_dir().parent)
    printed = [_shape(ln, root) for ln in capsys.readouterr().out.splitlines()]
    shown = _console_block("encoders.md", "quash cache info")
    assert [_shape(ln, "/home/me/.cache/quash-plugins") for ln in shown] == printed


def test_dimension_mismatch_is_the_message_the_docs_show(tmp_path, monkeypatch, capsys):
    """docs/encoders.md quotes the error of `quash query lseg_map.npz chair` word for word."""
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    E = np.random.default_rng(1).normal(size=(10, 512)).astype(np.float32)
    write_npz_map(LatentMap(E), tmp_path / "lseg_map.npz")
    monkeypatch.chdir(tmp_path)
    assert main(["query", "lseg_map.npz", "chair", "--device", "cpu"]) == 1
    printed = " ".join(capsys.readouterr().err.split())
    shown = " ".join(" ".join(_console_block("encoders.md", "quash query lseg_map.npz")).split())
    assert shown in printed, (shown, printed)
