"""A config, word list, taxonomy or template file that is a pipe, a device or a folder
is refused at once, naming the file, instead of waiting for ever.

Before, ``quash query MAP chair -c FIFO`` waited for a writer for ever, and
``-c /dev/zero`` read until memory ran out.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from _time_limit import time_limit

from quash_plugins import QuashConfig
from quash_plugins.core.errors import ConfigError, QuashError
from quash_plugins.core.yaml_files import load_yaml, read_text_file

pytestmark = pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs (POSIX)")


def _special(tmp_path: Path, kind: str, name: str) -> tuple[Path, str]:
    """A path of ``kind`` named like ``name`` and the word the error must use."""
    if kind == "fifo":
        path = tmp_path / name
        os.mkfifo(path)
        return path, "pipe (FIFO)"
    if kind == "folder":
        path = tmp_path / name
        path.mkdir()
        return path, "folder"
    path = tmp_path / name  # a link named like the file a loader expects
    path.symlink_to("/dev/zero")
    return path, "device"


KINDS = ["fifo", "folder", "link-to-dev-zero"]


@pytest.mark.parametrize("kind", KINDS)
def test_read_text_file_refuses_what_is_not_a_regular_file(tmp_path, kind):
    path, word = _special(tmp_path, kind, "c.yaml")
    with time_limit(20), pytest.raises(ConfigError) as info:
        read_text_file(path, "config file")
    assert str(path) in str(info.value) and word in str(info.value)


def test_read_text_file_reads_a_regular_file_and_names_a_binary_one(tmp_path):
    good = tmp_path / "c.yaml"
    good.write_text("encoder: minilm  # ünïcode\n", encoding="utf-8")
    assert read_text_file(good) == good.read_text(encoding="utf-8")
    binary = tmp_path / "map.npz"
    binary.write_bytes(b"PK\x03\x04\xff\xfe")
    with pytest.raises(ConfigError, match=r"map\.npz: it is not UTF-8"):
        read_text_file(binary, "config file")


@pytest.mark.parametrize("kind", KINDS)
def test_every_text_loader_refuses_a_special_file(tmp_path, kind):
    from quash_plugins.core.text import load_templates
    from quash_plugins.encoders import TableEncoder
    from quash_plugins.heuristics._data import read_word_list
    from quash_plugins.heuristics._taxonomy import load_taxonomy

    cases = {
        "c.yaml": lambda p: QuashConfig.from_yaml(p),
        "l.yaml": lambda p: load_yaml(p),
        "t.txt": lambda p: load_templates(str(p)),
        "t.py": lambda p: load_templates(str(p)),
        "v.txt": lambda p: read_word_list(str(p), "vocabulary.txt", "vocabulary"),
        "tax.yaml": lambda p: load_taxonomy(str(p)),
        "enc.yaml": lambda p: TableEncoder(file=str(p)).dim,
    }
    for name, load in cases.items():
        folder = tmp_path / name.replace(".", "_")
        folder.mkdir()
        path, word = _special(folder, kind, name)
        with time_limit(20), pytest.raises(QuashError) as info:
            load(path)
        assert word in str(info.value), (name, str(info.value))


def test_cli_config_that_is_a_fifo_is_refused(tiny_world, tmp_path, capsys):
    from quash_plugins.cli.main import main

    fifo = tmp_path / "quash.yaml"
    os.mkfifo(fifo)
    with time_limit(20):
        assert main(["query", str(tiny_world["map"]), "chair", "-c", str(fifo)]) == 1
    err = capsys.readouterr().err
    assert f"Config file {fifo} is a pipe (FIFO), not a regular file" in err


def test_a_file_this_user_may_not_read_says_so_with_the_fix(tmp_path, monkeypatch):
    """'Permission denied' alone gave no fix (root reads every file, so the denial is
    made by the stand-in os.open below)."""
    f = tmp_path / "q.yaml"
    f.write_text("present: [chair]\n", encoding="utf-8")
    real_open = os.open

    def denied(path, *args, **kwargs):
        if Path(path) == f:
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", denied)
    with pytest.raises(ConfigError) as err:
        read_text_file(f, "query file")
    msg = str(err.value)
    assert f"Cannot read query file {f}: Permission denied." in msg
    assert "make it readable, or give a copy this user can read" in msg
