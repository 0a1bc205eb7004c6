"""Hostile YAML: an alias bomb, recursive aliases and deep nesting are refused quickly,
by every loader of the package; fuzzed configs fail with ConfigError or load.

The bomb is the issue's: nine nested aliases (9**9 strings once expanded), which hung
``quash query -c`` for minutes and took gigabytes.
"""

from __future__ import annotations

import contextlib
import subprocess
import sys
from pathlib import Path

import pytest
from _time_limit import time_limit
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from quash_plugins import QuashConfig
from quash_plugins.core import config as config_module
from quash_plugins.core import yaml_files
from quash_plugins.core.errors import ConfigError, QuashError
from quash_plugins.core.yaml_files import load_yaml, load_yaml_text


def _levels(prefix: str) -> list[str]:
    """The nine levels of the bomb, as mapping entries (``prefix=""``) or list items."""
    lol = ", ".join(['"lol"'] * 9)
    rows = [f"{prefix}&l0 [{lol}]"]
    rows += [f"{prefix}&l{i} [{', '.join([f'*l{i - 1}'] * 9)}]" for i in range(1, 9)]
    return rows


BOMB_BODY = "\n".join(row.replace("&l", f"l{i}: &l", 1) for i, row in enumerate(_levels("")))
LIST_BOMB = "\n".join(_levels("- "))


def _bomb(path: Path, tail: str) -> Path:
    path.write_text(BOMB_BODY + "\n" + tail + "\n")
    return path


def test_alias_bomb_config_is_refused_by_the_cli_within_seconds(tiny_world, tmp_path):
    cfg = _bomb(tmp_path / "bomb.yaml", "negatives: *l8")
    proc = subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", "query", str(tiny_world["map"]), "chair"]
        + ["-c", str(cfg)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == 1, proc.stderr
    assert f"{cfg}: the YAML's aliases" in proc.stderr and "billion laughs" in proc.stderr


@pytest.mark.parametrize(
    "tail", ["negatives: *l8", "encoder: {name: minilm, extra: *l8}", "name: x\nseed: 1"]
)
def test_alias_bomb_is_refused_by_load_yaml(tmp_path, tail):
    path = _bomb(tmp_path / "c.yaml", tail)
    with time_limit(10), pytest.raises(ConfigError, match="aliases"):
        QuashConfig.from_yaml(path)


def test_every_yaml_loader_is_bounded(tmp_path):
    from quash_plugins.adapters._vlmaps_common import _names_from_file
    from quash_plugins.cli._config_opts import key_values
    from quash_plugins.core.errors import MapFormatError
    from quash_plugins.core.text import load_templates
    from quash_plugins.encoders import TableEncoder
    from quash_plugins.heuristics._data import read_word_list
    from quash_plugins.heuristics._taxonomy import load_taxonomy

    mapping = _bomb(tmp_path / "m.yaml", "chair: *l8")
    listing = tmp_path / "l.yaml"
    listing.write_text(LIST_BOMB + "\n")
    cases = [
        (lambda: load_taxonomy(str(mapping)), ConfigError),
        (lambda: load_templates(str(listing)), ConfigError),
        (lambda: read_word_list(str(listing), "vocabulary.txt", "vocabulary"), ConfigError),
        (lambda: TableEncoder(file=str(mapping)).dim, QuashError),
        (lambda: _names_from_file(mapping), MapFormatError),
        (lambda: key_values(["x=" + BOMB_BODY.replace("\n", ", ").join("{}")], "-o"), QuashError),
    ]
    for load, error in cases:
        with time_limit(10), pytest.raises(error):
            load()


def test_recursive_alias_and_deep_nesting_are_refused(tmp_path):
    rec = tmp_path / "rec.yaml"
    rec.write_text("negatives: &a [other, *a]\n")
    with time_limit(10), pytest.raises(ConfigError, match="recursive alias"):
        load_yaml(rec)
    deep = tmp_path / "deep.yaml"
    deep.write_text("[" * 20000 + "]" * 20000)
    with time_limit(20), pytest.raises(ConfigError, match=str(deep)):
        load_yaml(deep)


def test_ordinary_aliases_still_work_and_the_bound_is_on_expansion(monkeypatch):
    text = (
        "heuristic: {name: combine, synonyms: &s {name: none}, antonyms: *s}\n"
        "negatives: &n [other, thing]\n"
    )
    cfg = QuashConfig.from_dict(load_yaml_text(text, "c.yaml"))
    assert cfg.heuristic.params["antonyms"] == cfg.heuristic.params["synonyms"]
    monkeypatch.setattr(yaml_files, "MAX_ALIAS_EXPANSION", 50)
    doc = "a: &a [" + ", ".join(["x"] * 9) + "]\n"
    assert load_yaml_text(doc + "b: [*a, *a, *a, *a]\n")  # 40 extra nodes
    with pytest.raises(ConfigError, match="more than 50 extra nodes"):
        load_yaml_text(doc + "b: [*a, *a, *a, *a, *a, *a]\n")  # 60 extra nodes
    assert load_yaml_text("big: [" + ", ".join(["x"] * 500) + "]\n")  # no alias: no bound


KEYS = [f.name for f in config_module.dataclasses.fields(QuashConfig)] + ["classifer", "x"]
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-(2**70), 2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=20),
)
VALUES = st.recursive(
    SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4)
        | st.dictionaries(
            st.one_of(st.sampled_from(["name", "C", "file"]), st.text(max_size=8)),
            inner,
            max_size=4,
        )
    ),
    max_leaves=12,
)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=6))
def test_fuzzed_configs_load_or_fail_with_config_error(data):
    try:
        cfg = QuashConfig.from_dict(data)
    except ConfigError:
        return
    assert isinstance(cfg, QuashConfig)


@settings(max_examples=200, deadline=None)
@given(st.text(alphabet=st.sampled_from(list("&*ab:[]{},-\n '\"!#|>%@`x1")), max_size=80))
def test_fuzzed_yaml_text_loads_or_fails_with_config_error(text):
    try:
        data = load_yaml_text(text, "fuzz.yaml")
    except ConfigError as exc:
        assert str(exc).startswith("fuzz.yaml")
        return
    with contextlib.suppress(ConfigError):
        QuashConfig.from_dict(data)
