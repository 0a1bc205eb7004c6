"""``quash plugins`` says which plugin distributions are editable installs.

An editable install (``pip install -e``) or a source tree found first changes its code
without its version, so the version alone does not say what runs. The table's version
column reads ``0.3.0 (editable)`` for one, and ``--json`` gives each row ``editable``.
The distributions here are real ``importlib.metadata`` ones, laid out in a folder on
``sys.path`` as an installer (or setuptools' ``egg_info``) leaves them.
"""

from __future__ import annotations

import importlib
import json
import re
import sys

import pytest

from quash_plugins.cli.main import main
from quash_plugins.core import registry

_MODULE = """
from quash_plugins import Heuristic


class Demo(Heuristic):
    def expand(self, query, context=None):
        raise NotImplementedError
"""

#: name -> (version, how it is installed, what the table and --json must say)
INSTALLS = {
    "qp-edit-demo": ("0.3.0", "editable", True),  # pip install -e: direct_url.json
    "qp-release-demo": ("1.2.0", "release", False),  # pip install DIR: RECORD, not editable
    "qp-wheel-demo": ("2.0.1", "wheel", False),  # from a wheel: RECORD, no direct_url.json
    "qp-tree-demo": ("0.0.7", "source-tree", True),  # a project's NAME.egg-info, no RECORD
}


def _install(root, name, version, how):
    """Lay out distribution ``name`` with one heuristic entry point, as ``how`` leaves it."""
    module = name.replace("-", "_")
    (root / f"{module}.py").write_text(_MODULE, encoding="utf-8")
    entry_points = f"[quash_plugins.heuristics]\n{name} = {module}:Demo\n"
    meta = f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n"
    if how == "source-tree":
        info = root / f"{module}.egg-info"
        info.mkdir()
        (info / "PKG-INFO").write_text(meta, encoding="utf-8")
        (info / "SOURCES.txt").write_text(f"pyproject.toml\n{module}.py\n", encoding="utf-8")
    else:
        info = root / f"{module}-{version}.dist-info"
        info.mkdir()
        (info / "METADATA").write_text(meta, encoding="utf-8")
        (info / "RECORD").write_text(f"{module}.py,,\n", encoding="utf-8")
        if how in ("editable", "release"):
            dir_info = {"editable": True} if how == "editable" else {}
            url = {"url": f"file:///src/{name}", "dir_info": dir_info}
            (info / "direct_url.json").write_text(json.dumps(url), encoding="utf-8")
    (info / "entry_points.txt").write_text(entry_points, encoding="utf-8")


@pytest.fixture
def installed(tmp_path, monkeypatch):
    for name, (version, how, _) in INSTALLS.items():
        _install(tmp_path, name, version, how)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    registry.refresh()
    yield
    monkeypatch.undo()  # off sys.path before the registry scans again
    for name in INSTALLS:
        module = name.replace("-", "_")
        sys.modules.pop(module, None)
        registry._DISTRIBUTIONS.pop(module, None)
    importlib.invalidate_caches()
    registry.refresh()


def test_json_rows_say_whether_the_distribution_is_editable(installed, capsys):
    assert main(["plugins", "--kind", "heuristics", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    for name, (version, _, editable) in INSTALLS.items():
        row = rows[name]
        assert row["distribution"] == name and row["status"] == "ok", row
        assert row["version"] == version  # the version itself, unchanged
        assert row["editable"] is editable, row
    assert all(isinstance(r["editable"], bool) for r in rows.values())


def test_the_version_column_marks_editable_installs(installed, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # one line per row
    assert main(["plugins", "--kind", "heuristics"]) == 0
    out = capsys.readouterr().out
    for name, (version, _, editable) in INSTALLS.items():
        (line,) = [row for row in out.splitlines() if f" {name} " in row]
        cells = re.split(r"\s{2,}", line.strip())  # columns: two spaces or more apart
        assert cells[2] == name
        assert cells[3] == (f"{version} (editable)" if editable else version), line


def test_each_plugin_is_one_line_at_80_columns(capsys, monkeypatch):
    """Boxed, the table was 83 columns wide with the built-ins' '0.1.0 (editable)': at 80
    every row took two lines. Each row is one line of at most 80 columns."""
    from quash_plugins.cli.cmd_plugins import version_text

    monkeypatch.setenv("COLUMNS", "80")
    infos = registry.plugins(load=True)
    assert main(["plugins"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(line) for line in lines) <= 80
    for info in infos:
        cells = [info.kind, info.name, info.dist, version_text(info)]
        assert any(re.split(r"\s{2,}", line.strip())[:4] == cells for line in lines), cells


def test_a_plugin_registered_in_the_process_is_not_editable(capsys):
    from quash_plugins import Heuristic

    class InProcess(Heuristic):
        def expand(self, query, context=None):
            raise NotImplementedError

    # a label that names an installed editable distribution is still only a label
    registry.register("heuristics", "in-process-demo", InProcess, dist="quash-plugins")
    try:
        assert main(["plugins", "--kind", "heuristics", "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)
        (row,) = [r for r in rows if r["name"] == "in-process-demo" and r["version"] == ""]
        assert row["editable"] is False
    finally:
        registry.unregister("heuristics", "in-process-demo", dist="quash-plugins")
    assert "in-process-demo" not in registry.available("heuristics")
