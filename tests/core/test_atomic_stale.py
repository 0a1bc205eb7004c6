"""A temporary output left by a quash process killed outright is removed by the next
write of the same output; nothing else is ever touched (core/atomic.py, remove_stale).

A process killed with SIGKILL cannot clean up; its temporary names carry the machine and
the process number, so a later write knows which ones are stale. The end-to-end case (a
real ``quash convert`` killed mid-write) is in tests/cli/test_signals.py.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys

import pytest

from quash_plugins.core import atomic


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The number of a process that has run and been reaped."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    if not atomic._process_gone(proc.pid):  # pragma: no cover - reused at once
        pytest.skip("the process number was reused")
    return proc.pid


def _name(
    out: str, kind: str, pid: int, suffix: str = "", host: str | None = None, rand: str = "0123abcd"
) -> str:
    return f".{out}.quash-{kind}-{host or atomic._host()}-{pid}-{rand}{suffix}"


def test_a_dead_process_s_temporary_file_is_removed_by_the_next_write(tmp_path, dead_pid, caplog):
    stale = tmp_path / _name("r.npz", "tmp", dead_pid, ".npz")
    stale.write_bytes(b"half a result")
    with (
        caplog.at_level(logging.INFO, "quash_plugins"),
        atomic.atomic_write(tmp_path / "r.npz", ".npz") as tmp,
    ):
        tmp.write_bytes(b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.npz"]
    assert f"removed {stale}" in caplog.text
    assert f"quash process {dead_pid}" in caplog.text


def test_a_dead_process_s_temporary_store_is_removed_by_the_next_write(tmp_path, dead_pid):
    stale = tmp_path / _name("r.zarr", "tmp", dead_pid)
    (stale / "scores").mkdir(parents=True)
    (stale / "zarr.json").write_text("{}")
    with atomic.atomic_dir(tmp_path / "r.zarr") as tmp:
        tmp.mkdir()
        (tmp / "zarr.json").write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr"]


def test_only_what_quash_certainly_made_for_this_output_is_removed(tmp_path, dead_pid):
    out = tmp_path / "r.npz"
    keep = {
        # a process that still runs: this test's parent, and this process itself
        _name("r.npz", "tmp", os.getppid(), ".npz"): "file",
        _name("r.npz", "tmp", os.getpid(), ".npz"): "file",
        # another machine: its process numbers mean nothing here
        _name("r.npz", "tmp", dead_pid, ".npz", host="abcdef"): "file",
        # another output's temporary file
        _name("s.npz", "tmp", dead_pid, ".npz"): "file",
        # a name without quash's mark (the names before it carried one)
        f".r.npz.{'0123abcd'}.npz": "file",
        ".r.npz.tmp-123-0123abcd": "dir",
        ".r.npz.notes": "file",
        # quash's name on something quash does not make there, or a copy of one
        _name("r.npz", "tmp", dead_pid, ".npz") + "~": "file",  # a copy of one
        _name("r.npz", "tmp", dead_pid, ".tmp"): "dir",  # a file's name, on a folder
        _name("r.npz", "tmp", dead_pid): "file",  # a folder's name, on a file
        _name("r.npz", "old", dead_pid, ".npz"): "dir",
        _name("r.npz", "tmp", dead_pid, ".rrd") + "-link": "link",
    }
    target = tmp_path / "target"
    target.mkdir()
    (target / "precious").write_text("mine")
    link = tmp_path / _name("r.npz", "tmp", dead_pid, rand="4567cdef")
    link.symlink_to(target)  # a folder's name, on a link to a folder
    for name, kind in keep.items():
        p = tmp_path / name
        if kind == "dir":
            p.mkdir()
        elif kind == "link":
            p.symlink_to(target / "precious")
        else:
            p.write_text("x")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert atomic.remove_stale(out) == []
    with atomic.atomic_write(out, ".npz") as tmp:
        tmp.write_bytes(b"whole")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([*before, "r.npz"])
    assert (target / "precious").read_text() == "mine"


def test_a_previous_store_moved_aside_comes_back_when_its_replacement_never_came(
    tmp_path, dead_pid
):
    """Killed between moving the old store aside and renaming the new one into place."""
    out = tmp_path / "r.zarr"
    old = tmp_path / _name("r.zarr", "old", dead_pid)
    old.mkdir()
    (old / "zarr.json").write_text("previous")
    assert atomic.remove_stale(out) == []
    assert (out / "zarr.json").read_text() == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr"]


def test_a_previous_store_moved_aside_is_removed_once_its_replacement_is_in_place(
    tmp_path, dead_pid
):
    """Killed after the new store was in place, before the old one was removed."""
    out = tmp_path / "r.zarr"
    out.mkdir()
    (out / "zarr.json").write_text("new")
    old = tmp_path / _name("r.zarr", "old", dead_pid)
    old.mkdir()
    (old / "zarr.json").write_text("previous")
    assert atomic.remove_stale(out) == [old]
    assert (out / "zarr.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.zarr"]


def test_the_names_made_carry_this_process_and_machine(tmp_path):
    """What remove_stale reads in a name is what atomic_write and atomic_dir put there."""
    seen = []
    with atomic.atomic_write(tmp_path / "r.rrd", ".tmp") as tmp:
        seen.append(tmp.name)
    with atomic.atomic_dir(tmp_path / "r.zarr") as tmp:
        tmp.mkdir()
        seen.append(tmp.name)
    for name, out in zip(seen, ["r.rrd", "r.zarr"]):
        m = atomic._STALE.fullmatch(name, len(f".{out}."))
        assert m is not None, name
        assert (m["kind"], m["host"], int(m["pid"])) == ("tmp", atomic._host(), os.getpid())


def test_a_temporary_folder_written_into_after_an_interrupt_is_removed_at_exit(
    tmp_path, monkeypatch
):
    """A Dask worker of the interrupted command may write one more chunk into the
    temporary store after it was removed; it is removed again when the process exits."""
    at_exit = []
    monkeypatch.setattr(atomic.atexit, "register", lambda f, *a, **k: at_exit.append((f, a, k)))
    out = tmp_path / "r.zarr"
    with pytest.raises(KeyboardInterrupt), atomic.atomic_dir(out) as tmp:
        (tmp / "c").mkdir(parents=True)
        raise KeyboardInterrupt
    assert not tmp.exists()
    (tmp / "c" / "5").mkdir(parents=True)  # the late write
    for f, a, k in at_exit:
        f(*a, **k)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
