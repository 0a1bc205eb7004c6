"""A plugin registered under a group quash-plugins does not read is named, with the fix.

Before: an entry point in ``quash_plugins.encoder`` (singular) or ``quash_plugins`` was
silently ignored; ``quash plugins`` did not list it, and a config naming it was told
only that the name is not registered, with a similar built-in name as a guess.
"""

from __future__ import annotations

import pytest

from quash_plugins.cli.main import main
from quash_plugins.core import registry
from quash_plugins.core.errors import PluginError

ENTRY_POINTS = """\
[quash_plugins.encoder]
lab-encoder = lab_encoders:LabEncoder

[quash_plugins]
lab-heuristic = lab_encoders:LabHeuristic

[quash.encoders]
lab-short = lab_encoders:LabEncoder

[quash.commands]
lab-command = lab_encoders:main

[console_scripts]
lab = lab_encoders:main
"""


@pytest.fixture
def misplaced(tmp_path, monkeypatch):
    """An installed distribution (its metadata only) with entry points in wrong groups."""
    info = tmp_path / "lab_encoders-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-encoders\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.syspath_prepend(str(tmp_path))
    registry.refresh()
    yield
    registry.refresh()


def test_a_config_naming_it_is_told_the_group_to_use(misplaced):
    with pytest.raises(PluginError) as err:
        registry.create("encoders", "lab-encoder")
    msg = str(err.value)
    assert "'lab-encoder' is not registered" in msg
    assert "'lab-encoders' registers 'lab-encoder'" in msg
    assert "group 'quash_plugins.encoder'" in msg and "to 'quash_plugins.encoders'" in msg
    assert "Did you mean" not in msg


def test_a_group_without_a_kind_lists_the_four(misplaced):
    msg = str(pytest.raises(PluginError, registry.create, "heuristics", "lab-heuristic").value)
    assert "group 'quash_plugins'" in msg
    assert "'quash_plugins.encoders', 'quash_plugins.heuristics'" in msg


def test_quash_plugins_lists_it_below_the_table(misplaced, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["plugins", "--kind", "encoders"]) == 0
    out = capsys.readouterr().out
    assert "not read: lab-encoder (lab-encoders)" in out
    assert "move it to 'quash_plugins.encoders'" in out
    assert "lab-heuristic" in out  # its group names no kind: shown for every kind
    assert main(["plugins", "--kind", "adapters"]) == 0
    assert "not read: lab-encoder " not in capsys.readouterr().out  # meant for encoders
    names = {m.name for m in registry.misplaced_entry_points()}
    assert {"lab-encoder", "lab-heuristic"} <= names and "lab" not in names


def test_the_group_named_after_the_command_is_named_too(misplaced, capsys, monkeypatch):
    # 'quash' is the command, so '[project.entry-points."quash.encoders"]' is an easy slip;
    # it was not named: the plugin was missing from `quash plugins` with no word why.
    msg = str(pytest.raises(PluginError, registry.create, "encoders", "lab-short").value)
    assert "'lab-encoders' registers 'lab-short'" in msg
    assert "group 'quash.encoders'" in msg and "to 'quash_plugins.encoders'" in msg
    monkeypatch.setenv("COLUMNS", "200")
    assert main(["plugins", "--kind", "encoders"]) == 0
    assert "not read: lab-short (lab-encoders)" in capsys.readouterr().out
    # a 'quash...' group that names no kind is another project's, not a slip of ours
    assert "lab-command" not in {m.name for m in registry.misplaced_entry_points()}


def test_a_name_registered_as_another_kind_says_so():
    msg = str(pytest.raises(PluginError, registry.create, "heuristics", "minilm").value)
    assert "'minilm' is registered as encoder (in group 'quash_plugins.encoders')" in msg
