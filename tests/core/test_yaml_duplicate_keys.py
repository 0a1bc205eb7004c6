"""A key given twice in a YAML mapping is refused, naming the file, the line and the key.

PyYAML keeps the last value without a word, so a config that sets ``threshold:`` twice,
or a query file with two ``present:`` sections, silently lost one of them. Every loader
of the package goes through :func:`quash_plugins.core.yaml_files.load_yaml` (or
``load_yaml_text``); what the package ships and writes, and the docs' YAML, still load.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from quash_plugins import QuashConfig
from quash_plugins.core.errors import ConfigError, QuashError
from quash_plugins.core.shipped import config_dir, shipped_configs
from quash_plugins.core.yaml_files import load_yaml, load_yaml_text

ROOT = Path(__file__).resolve().parents[2]


def test_a_config_with_a_key_given_twice_is_refused_with_file_line_and_key(tmp_path):
    cfg = tmp_path / "dup.yaml"
    cfg.write_text("name: a\nthreshold: 0.1\nencoder: minilm\nthreshold: 0.2\n")
    with pytest.raises(ConfigError) as info:
        QuashConfig.from_yaml(cfg)
    msg = str(info.value)
    assert msg.startswith(f"{cfg}:4: duplicate key 'threshold'"), msg
    assert "line 2" in msg


def test_a_nested_duplicate_is_refused_at_its_own_line(tmp_path):
    cfg = tmp_path / "dup.yaml"
    cfg.write_text("name: a\nclassifier:\n  name: svm-rbf\n  C: 1.0\n  C: 10.0\n")
    with pytest.raises(ConfigError, match=rf"^{re.escape(str(cfg))}:5: duplicate key 'C'"):
        load_yaml(cfg)
    # in a flow mapping too
    with pytest.raises(ConfigError, match=r"^t\.yaml:1: duplicate key 'k'"):
        load_yaml_text("classifier: {name: nearest-sample, k: 2, k: 3}\n", "t.yaml")


def test_keys_that_load_equal_are_duplicates():
    # 1 and 1.0 are one key of the loaded dict: one value would be lost
    with pytest.raises(ConfigError, match=r"t\.yaml:2: duplicate key 1\.0"):
        load_yaml_text("1: a\n1.0: b\n", "t.yaml")


def test_merge_keys_may_still_be_overridden():
    text = "base: &b {name: svm-rbf, C: 1.0}\nclassifier:\n  <<: *b\n  C: 10.0\n"
    assert load_yaml_text(text, "t.yaml")["classifier"] == {"name": "svm-rbf", "C": 10.0}


def test_a_query_file_with_two_present_sections_is_refused(tmp_path):
    from quash_plugins.evaluation.queries import load_query_file

    f = tmp_path / "q.yaml"
    f.write_text("present: [chair]\nabsent: [piano]\npresent: [sofa]\n")
    with pytest.raises(QuashError, match=rf"^{re.escape(str(f))}:3: duplicate key 'present'"):
        load_query_file(f)
    f.write_text("present:\n  bunk bed: bed\n  bunk bed: sofa\n")
    with pytest.raises(QuashError, match=r"q\.yaml:3: duplicate key 'bunk bed'"):
        load_query_file(f)


def test_a_taxonomy_with_a_label_given_twice_is_refused(tmp_path):
    from quash_plugins.heuristics._taxonomy import load_taxonomy

    f = tmp_path / "tax.yaml"
    f.write_text("chair: [armchair]\nsofa: [couch]\nchair: [stool]\n")
    with pytest.raises(ConfigError, match=r"tax\.yaml:3: duplicate key 'chair'"):
        load_taxonomy(str(f))


def test_the_cli_refuses_a_duplicate_key_config_before_reading_the_map(tiny_world, tmp_path):
    cfg = tmp_path / "dup.yaml"
    cfg.write_text(tiny_world["config"].read_text() + "classifier: svm-rbf\n")
    proc = subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", "query", str(tiny_world["map"])]
        + ["chair", "-c", str(cfg)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 1, proc.stderr
    assert f"{cfg}:6: duplicate key 'classifier' (first given on line 5)" in proc.stderr
    assert "read points map" not in proc.stderr


def test_every_shipped_yaml_file_loads():
    files = sorted(config_dir().glob("*.yaml"))
    assert files and shipped_configs()
    for path in files:
        load_yaml(path)
    for shipped in shipped_configs():
        QuashConfig.from_yaml(shipped.path)


def test_every_yaml_block_of_the_docs_loads():
    docs = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    n = 0
    for doc in docs:
        text = doc.read_text(encoding="utf-8")
        for m in re.finditer(r"^```ya?ml\n(.*?)^```", text, flags=re.S | re.M):
            line = text[: m.start()].count("\n") + 2
            load_yaml_text(m.group(1), f"{doc.name}:{line}")
            n += 1
    assert n >= 10


@pytest.mark.parametrize("table", ["a", "b"])
def test_make_scene_files_load(minilm_scene, table, capsys):
    from quash_plugins.cli.main import main

    stem = str(minilm_scene)[: -len(".npz")]
    for suffix in ("taxonomy", "queries", "open-queries"):
        load_yaml(f"{stem}.{suffix}.yaml")
    assert main(["make-scene", "--show-classes", "--classes", table]) == 0
    load_yaml_text(capsys.readouterr().out, f"--show-classes --classes {table}")
