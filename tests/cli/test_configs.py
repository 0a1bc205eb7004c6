"""Shipped configs by name (``-c demo:quash-taxonomy``) and ``quash configs``."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from quash_plugins.cli.main import main
from quash_plugins.core.config import QuashConfig
from quash_plugins.core.errors import ConfigError
from quash_plugins.core.shipped import find_shipped, resolve_config_path, shipped_configs

#: Encoders whose model ships with the package (no download).
SHIPPED_ENCODERS = {"minilm", "table"}


def test_every_shipped_config_loads_and_says_what_it_needs():
    configs = shipped_configs()
    names = {c.name for c in configs}
    assert {"demo:quash-taxonomy", "demo:vlmaps", "lseg:vlmaps"} <= names
    assert "demo:taxonomy" not in names  # the demo's taxonomy file is not a method
    for c in configs:
        cfg = QuashConfig.from_yaml(c.name)
        assert cfg.source and c.description.endswith("."), c
        # A config runs offline exactly when its encoder ships with the package.
        assert c.offline == (cfg.encoder.name in SHIPPED_ENCODERS), c
        if not c.offline:
            assert "weights" in c.needs, c


@pytest.mark.slow
def test_offline_configs_run_offline():
    """Each ``demo:*`` config builds and expands a query with what the package ships."""
    from quash_plugins import Quash
    from quash_plugins.core.types import LatentMap

    # The label-list configs take their list from the map: give them one with label names.
    labelled = LatentMap(
        embeddings=np.eye(3, 8, dtype=np.float32),
        labels=np.arange(3),
        label_names=["chair", "sofa", "table"],
    )
    for c in shipped_configs():
        if c.offline:
            quash = Quash.from_config(c.name, cache=None)
            qs = quash.expand("chair", labelled)
            assert qs.positives[0] == "chair" and qs.negatives, c.name
            X, y, _ = quash.training_set(qs)
            assert X.shape[0] == len(y) > 1, c.name


def test_names_resolve_and_mistakes_say_what_exists(tmp_path, monkeypatch):
    assert resolve_config_path("demo:quash-taxonomy").name == "demo-quash-taxonomy.yaml"
    with pytest.raises(ConfigError, match="Did you mean demo:quash-taxonomy"):
        find_shipped("demo:quash-taxnomy")
    # a name like none in its group gets no guess: 'demo:' alone made 'demo:nope' look
    # like 'demo:lerf'; a misspelt group is still guessed whole
    with pytest.raises(ConfigError) as err:
        find_shipped("demo:nope")
    assert "Did you mean" not in str(err.value) and "demo:lerf," in str(err.value)
    with pytest.raises(ConfigError, match="Did you mean demo:vlmaps"):
        find_shipped("dmeo:vlmaps")
    with pytest.raises(ConfigError, match=r"Config file not found: quash\.yaml.*demo:vlmaps"):
        resolve_config_path("quash.yaml")
    # A file of that name wins over the shipped one.
    monkeypatch.chdir(tmp_path)
    (tmp_path / "demo:vlmaps").write_text("name: mine\n")
    assert QuashConfig.from_yaml("demo:vlmaps").name == "mine"


def test_cli_takes_a_shipped_name_and_refuses_a_missing_file(capsys):
    assert main(["expand", "chair", "-c", "demo:quash-taxonomy", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["provenance"]["heuristic"] == "taxonomy" and "seat" in data["positives"]
    assert main(["expand", "chair", "-c", "quash.yaml"]) == 2
    err = capsys.readouterr().err
    assert "Config file not found: quash.yaml" in err and "demo:quash-taxonomy" in err


def test_quash_configs_lists_and_prints(capsys):
    assert main(["configs", "--json"]) == 0
    listed = {c["name"]: c for c in json.loads(capsys.readouterr().out)}
    assert listed["demo:quash-taxonomy"]["offline"] is True
    assert listed["lseg:vlmaps"]["offline"] is False
    assert "ViT-B-32" in listed["lseg:vlmaps"]["needs"]
    assert main(["configs"]) == 0
    table = capsys.readouterr().out
    for name in listed:
        assert name in table
    assert "nothing (offline" in table and "weights" in table
    assert main(["configs", "demo:vlmaps"]) == 0
    text = capsys.readouterr().out
    first, rest = text.split("\n", 1)
    assert first.startswith("# demo:vlmaps: ") and first.endswith("demo-vlmaps.yaml")
    assert yaml.safe_load(rest) == yaml.safe_load(find_shipped("demo:vlmaps").path.read_text())
    assert main(["configs", "demo:nope"]) == 2


def test_a_bad_adapter_option_names_the_config_file_and_section(tiny_world, capsys, monkeypatch):
    """`adapter: {name: vlmaps, pose_typ: x}`: the error says it is q.yaml's adapter section."""
    pytest.importorskip("h5py")
    from quash_plugins.adapters._vlmaps import VLMapsAdapter

    monkeypatch.chdir(tiny_world["dir"])
    h5 = VLMapsAdapter().write_example(tiny_world["dir"])
    cfg = yaml.safe_load(tiny_world["config"].read_text())
    cfg["adapter"] = {"name": "vlmaps", "pose_typ": "x"}
    (tiny_world["dir"] / "q.yaml").write_text(yaml.safe_dump(cfg))
    assert main(["query", str(h5), "chair", "-c", "q.yaml"]) != 0
    err = " ".join(capsys.readouterr().err.split())
    assert "q.yaml: adapter: Adapter 'vlmaps' does not accept parameter 'pose_typ'" in err, err
    assert "Did you mean 'pose_type'?" in err


def test_a_missing_config_suggests_the_near_names(tmp_path, monkeypatch, capsys):
    """`-c quash-labels` names the shipped configs of that name; `-c quash.yml` the
    file beside it with a close name; nothing close keeps the full list."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=r"Did you mean demo:quash-labels or lseg:quash-labels\?"):
        resolve_config_path("quash-labels")
    (tmp_path / "quash.yaml").write_text("encoder: minilm\n")
    with pytest.raises(ConfigError, match=r"quash\.yml\. Did you mean quash\.yaml\?"):
        resolve_config_path("quash.yml")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "quash.yaml").write_text("encoder: minilm\n")
    with pytest.raises(ConfigError, match=r"Did you mean sub/quash\.yaml\?"):
        resolve_config_path("sub/quash.yml")
    # a mistyped folder: the file in the folder of a near name
    with pytest.raises(ConfigError, match=r"Did you mean sub/quash\.yaml\?"):
        resolve_config_path("subs/quash.yaml")
    with pytest.raises(ConfigError, match=r"shipped: .*demo:vlmaps"):
        resolve_config_path("nothing-like-it")
    # a shipped config's own file name, as 'quash configs' lists the files: that one
    for ref in ("demo-quash-labels.yaml", "lseg-quash-labels.yml", "demo-quash-labels"):
        name = ref.split(".")[0].replace("-", ":", 1)
        with pytest.raises(ConfigError, match=rf"Did you mean {name}\?$"):
            resolve_config_path(ref)
    assert main(["query", "map.npz", "chair", "-c", "quash-labels"]) != 0
    assert "Did you mean demo:quash-labels or lseg:quash-labels?" in capsys.readouterr().err


def test_a_printed_config_saved_elsewhere_still_finds_its_files(tmp_path, capsys, monkeypatch):
    """``quash configs demo:quash-taxonomy > mine.yaml`` gave a copy whose relative
    ``file: demo-taxonomy.yaml`` resolved beside the copy (not found); the printed text
    names shipped files whole and is otherwise the shipped config."""
    monkeypatch.chdir(tmp_path)
    with_files = 0
    for c in shipped_configs():
        assert main(["configs", c.name]) == 0
        copy = tmp_path / "mine.yaml"
        copy.write_text(capsys.readouterr().out)
        shipped = yaml.safe_load(c.path.read_text())
        printed = yaml.safe_load(copy.read_text())
        heuristic = shipped.get("heuristic")
        if isinstance(heuristic, dict) and "file" in heuristic:
            with_files += 1
            whole = printed["heuristic"]["file"]
            assert whole == str(c.path.parent / heuristic["file"]), c.name
            loaded = QuashConfig.from_yaml(str(copy))
            assert loaded.heuristic.params["file"] == whole
            printed["heuristic"]["file"] = heuristic["file"]
        assert printed == shipped, c.name
    assert with_files >= 2  # demo:quash-taxonomy and demo:quash-taxonomy-svm


@pytest.mark.parametrize("columns", [60, 80, 100, 160])
def test_quash_configs_loses_no_text_at_any_width(columns, capsys, monkeypatch):
    """At 80 columns the description column was some 20 characters wide and a path in it
    was cut with an ellipsis ('benchmarks/bench_qual…'); every line now fits the
    terminal and every config's name, needs and description is there whole."""
    from quash_plugins.cli import cmd_configs
    from quash_plugins.core.shipped import shipped_configs

    monkeypatch.setenv("COLUMNS", str(columns))
    assert main(["configs"]) == 0
    out = capsys.readouterr().out
    assert "…" not in out
    assert max(len(line) for line in out.splitlines()) <= columns
    joined = "".join(out.split())
    for c in shipped_configs():
        for text in (c.name, c.needs or "", c.description):
            if columns < cmd_configs.NARROW:  # one block per config: its text in order
                assert "".join(text.split()) in joined, (c.name, text)
            else:  # a table: the columns interleave, but no word is cut
                assert all(word in out for word in text.split()), (c.name, text)
