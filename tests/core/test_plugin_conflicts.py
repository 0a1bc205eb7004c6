"""Real installed plugins that are broken, or that claim a built-in's name.

A pip-installed distribution claims the heuristic ``none`` (the default config's) and
ships an adapter that fails to import. Before: the default config failed ("claimed by
several distributions") and the broken adapter was reported only at DEBUG level during
a query. Now the built-in keeps its bare name with one warning, and the broken plugin
is warned about once at the default level.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from _pip import pip_install

from quash_plugins import Quash
from quash_plugins.core import registry

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

PYPROJECT = """\
[build-system]
requires = ["setuptools>=64"]
build-backend = "setuptools.build_meta"

[project]
name = "quash-shadow-plugin"
version = "0.0.1"
requires-python = ">=3.11"

[project.entry-points."quash_plugins.heuristics"]
none = "quash_shadow:Shadow"

[project.entry-points."quash_plugins.adapters"]
broken-adapter = "quash_shadow.missing:Nothing"
exits-on-import = "quash_shadow.exits:Nothing"

[tool.setuptools]
packages = ["quash_shadow"]
"""

MODULE = """\
from quash_plugins.core.interfaces import Heuristic
from quash_plugins.core.types import QuerySet


class Shadow(Heuristic):
    name = "none"

    def expand(self, query, context=None):
        return QuerySet(query, [query, "shadowed"], ["other"], {"heuristic": "shadow"})
"""

# A licence or driver check at import time that ends the process.
EXITS = """\
import sys

sys.exit("no licence file found")
"""


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    project = tmp_path_factory.mktemp("shadow")
    (project / "pyproject.toml").write_text(PYPROJECT)
    (project / "quash_shadow").mkdir()
    (project / "quash_shadow" / "__init__.py").write_text(MODULE)
    (project / "quash_shadow" / "exits.py").write_text(EXITS)
    target = tmp_path_factory.mktemp("site")
    pip_install(project, target)
    pip_install(EXAMPLES / "quash-broken-plugin", target)
    sys.path.insert(0, str(target))
    registry.refresh()
    yield target
    sys.path.remove(str(target))
    for name in [m for m in sys.modules if m.startswith(("quash_shadow", "quash_broken"))]:
        del sys.modules[name]
    registry.refresh()


def test_builtin_keeps_its_bare_name_and_the_other_is_reachable_qualified(installed, tiny_world):
    q = Quash.from_config(tiny_world["config"])  # heuristic: none
    assert q.expand("chair").positives == ["chair"]
    assert registry.info("heuristics", "none").dist == "quash-plugins"
    shadow = registry.create("heuristics", "quash-shadow-plugin:none")
    assert shadow.expand("chair").positives == ["chair", "shadowed"]


def _quash_cli(installed, *args, columns=None, check=False):
    """``quash ARGS`` in a subprocess that sees the installed plugins."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(installed), *sys.path])}
    if columns:
        env["COLUMNS"] = str(columns)
    return subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=check,
    )


def test_cli_default_level_warns_once_about_each(installed, tiny_world):
    cfg = tiny_world["dir"] / "default-heuristic.yaml"
    cfg.write_text(
        textwrap.dedent(
            f"""\
            encoder: {{name: table, file: {tiny_world["table"]}}}
            classifier: contrast
            """
        )
    )
    proc = _quash_cli(
        installed, "query", tiny_world["map"], "chair", "sofa", "-c", cfg, "--adapter", "auto"
    )
    assert proc.returncode == 0, proc.stderr
    err = " ".join(proc.stderr.split())
    assert err.count("Heuristic 'none' is also claimed by quash-shadow-plugin:none") == 1
    assert "Write 'quash-shadow-plugin:none'" in err
    assert err.count("Adapter plugin 'broken-adapter' from distribution") == 1
    assert "WARNING" in proc.stderr and "Fix or uninstall 'quash-shadow-plugin'" in err


def _table_rows(out: str) -> list[list[str]]:
    """The rows of 'quash plugins'' table: kind, name, distribution, version, status
    (its columns are set apart by two spaces or more, without rules)."""
    rows = [re.split(r"\s{2,}", line.strip()) for line in out.splitlines()]
    return [r for r in rows if len(r) == 5 and r[0] in registry.KINDS]


def test_cli_table_names_the_shadowed_plugin_as_a_config_spells_it(installed):
    proc = _quash_cli(installed, "plugins", "--kind", "heuristics", columns=120)
    rows = _table_rows(proc.stdout)
    names = {(r[1], r[2]) for r in rows}
    assert ("none", "quash-plugins") in names
    assert ("quash-shadow-plugin:none", "quash-shadow-plugin") in names


def test_cli_table_marks_the_shadowed_plugin_and_says_how_to_reach_it(installed):
    out = _quash_cli(installed, "plugins", "--kind", "heuristics", columns=160, check=True).stdout
    rows = {r[1]: r[4] for r in _table_rows(out)}
    assert rows["quash-shadow-plugin:none"] == "ok, shadowed"
    assert rows["none"] == "ok"
    flat = " ".join(out.split())
    assert "the built-in quash-plugins:none keeps the name 'none'" in flat
    assert "a config reaches this one as 'quash-shadow-plugin:none'" in flat
    listed = json.loads(_quash_cli(installed, "plugins", "--json", check=True).stdout)
    shadow = [
        r for r in listed if r["distribution"] == "quash-shadow-plugin" and r["name"] == "none"
    ]
    assert shadow and shadow[0]["shadowed_by"] == "quash-plugins:none"
    assert shadow[0]["config_name"] == "quash-shadow-plugin:none"


def test_a_plugin_that_calls_sys_exit_when_imported_is_listed_as_broken(installed, tiny_world):
    """Before: SystemExit is not an Exception, so the import error was not caught:
    `quash plugins` printed "no licence file found" and stopped, and every query with
    adapter: auto (which loads every adapter to sniff the map) did the same."""
    proc = _quash_cli(installed, "plugins", "--kind", "adapters", "--json")
    assert proc.returncode == 0, proc.stderr
    rows = {r["name"]: r for r in json.loads(proc.stdout)}
    exits = rows["exits-on-import"]
    assert exits["status"] == "error" and exits["distribution"] == "quash-shadow-plugin"
    assert "SystemExit: no licence file found" in exits["error"]
    assert "'quash_shadow.exits' calls sys.exit()" in exits["error"]
    assert rows["npz"]["status"] == "ok"
    config = tiny_world["config"]
    proc = _quash_cli(installed, "query", tiny_world["map"], "chair", "-c", config, "--json")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)  # the query was answered
    assert "Adapter plugin 'exits-on-import' from distribution" in " ".join(proc.stderr.split())
