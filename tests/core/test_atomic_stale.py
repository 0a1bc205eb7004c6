"""A temporary output left by a quash process killed outright is removed by the next
write of the same output; nothing else is ever touched (core/atomic.py, remove_stale).

A process killed with SIGKILL cannot clean up; its temporary names carry the machine and
the process number, and it held a lock on their lock file (``.NAME.quash-lck-...``) that
the kernel released, so a later write knows which ones are stale. A writer that still
runs holds its lock, even where its process number means nothing (another PID namespace:
simulated by forcing ``_process_gone``). The end-to-end case (a real ``quash convert``
killed mid-write) is in tests/cli/test_signals.py.
"""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from quash_plugins.core import _atomic_stale, atomic


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


def _lock(folder: Path, out: str, pid: int, host: str | None = None, rand: str = "0123abcd"):
    """The lock file a writer left, held by nobody now."""
    (folder / _name(out, "lck", pid, host=host, rand=rand)).write_text("")


def test_a_dead_process_s_temporary_file_is_removed_by_the_next_write(tmp_path, dead_pid, caplog):
    stale = tmp_path / _name("r.npz", "tmp", dead_pid, ".npz")
    stale.write_bytes(b"half a result")
    _lock(tmp_path, "r.npz", dead_pid)
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
    _lock(tmp_path, "r.zarr", dead_pid)
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
    for pid, host, rand in [
        (os.getppid(), None, "0123abcd"),
        (os.getpid(), None, "0123abcd"),
        (dead_pid, "abcdef", "0123abcd"),
        (dead_pid, None, "0123abcd"),
        (dead_pid, None, "4567cdef"),
    ]:  # their lock files, held by nobody: the other checks alone keep them
        _lock(tmp_path, "r.npz", pid, host=host, rand=rand)
    _lock(tmp_path, "s.npz", dead_pid)
    # the temporary of a process gone, but without a lock file (quash before locks)
    keep[_name("r.npz", "tmp", dead_pid, ".npz", rand="89abcdef")] = "file"
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
    _lock(tmp_path, "r.zarr", dead_pid)
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
    _lock(tmp_path, "r.zarr", dead_pid)
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
    monkeypatch.setattr(atomic, "_LEFT", atomic._LeftAtExit())  # none registered yet
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


def test_many_failed_writes_register_one_exit_handler_that_removes_every_temporary(
    tmp_path, monkeypatch
):
    """Each failed write registered an exit handler of its own: a long-lived process (a
    notebook writing many stores that fail) piled them up. One handler removes them all."""
    at_exit = []
    monkeypatch.setattr(atomic, "_LEFT", atomic._LeftAtExit())
    monkeypatch.setattr(atomic.atexit, "register", lambda f, *a, **k: at_exit.append((f, a, k)))
    tmps = []
    for i in range(5):
        with pytest.raises(RuntimeError), atomic.atomic_dir(tmp_path / f"r{i}.zarr") as tmp:
            (tmp / "c").mkdir(parents=True)
            raise RuntimeError("write failed")
        tmps.append(tmp)
        (tmp / "c" / "5").mkdir(parents=True)  # a late write by a worker
    assert len(at_exit) == 1
    assert atomic._LEFT.paths == set(tmps)
    f, a, k = at_exit[0]
    f(*a, **k)
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    assert atomic._LEFT.paths == set()  # removed: no longer kept


# A writer in a child process: atomic_dir or atomic_write of argv[1], which holds its
# temporary (a store, or a file) until the file argv[2] appears. With argv[3] == "aside"
# it stops instead once the previous store is moved aside; with "fork" it first forks a
# child that sleeps on (and would keep the lock, were it inherited).
WRITER = """
import os, sys, time
from pathlib import Path
from quash_plugins.core import atomic
out, go, how = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
def wait():
    print("ready", flush=True)
    while not go.exists():
        time.sleep(0.02)
replace = os.replace
def replace_then_wait(a, b):
    replace(a, b)
    if how == "aside" and ".quash-old-" in str(b):
        wait()
os.replace = replace_then_wait
if how == "fork" and os.fork() == 0:
    for _ in range(6000):  # until the test ends (go), at most two minutes
        if go.exists():
            break
        time.sleep(0.02)
    os._exit(0)
if out.suffix == ".zarr":
    with atomic.atomic_dir(out) as tmp:
        tmp.mkdir()
        (tmp / "zarr.json").write_text("new")
        if how != "aside":
            wait()
else:
    with atomic.atomic_write(out, out.suffix) as tmp:
        tmp.write_text("new")
        wait()
print("done", flush=True)
"""


def _writer(tmp_path: Path, out: Path, how: str = "hold") -> tuple[subprocess.Popen, Path]:
    go = tmp_path / "go"
    proc = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(out), str(go), how],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline() == "ready\n", proc.communicate()
    return proc, go


def _let_finish(proc: subprocess.Popen, go: Path) -> None:
    """Tell the writer to end its write; it must end well."""
    go.touch()
    stdout, stderr = proc.communicate(timeout=120)
    assert (proc.returncode, stdout) == (0, "done\n"), stderr


def _reap(proc: subprocess.Popen) -> None:
    """Kill the writer if a failed assertion left it running."""
    if proc.poll() is None:
        proc.kill()
        proc.wait()


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


@pytest.fixture
def any_pid_gone(monkeypatch):
    """Every process looks gone, as a writer in another PID namespace does."""
    monkeypatch.setattr(_atomic_stale, "_process_gone", lambda pid: True)


@pytest.mark.parametrize("name", ["r.zarr", "r.npz"])
def test_a_running_writer_s_temporary_is_left_even_when_its_process_looks_gone(
    tmp_path, any_pid_gone, name
):
    """Another PID namespace (a container, unshare --pid) or a machine of the same name
    sharing the folder: os.kill says its process is gone; its lock says it runs."""
    out = tmp_path / "out"
    out.mkdir()
    proc, go = _writer(tmp_path, out / name)
    try:
        before = _hidden(out)
        assert atomic.remove_stale(out / name) == []
        assert _hidden(out) == before
        assert any(".quash-tmp-" in n for n in before) and any(".quash-lck-" in n for n in before)
        _let_finish(proc, go)
    finally:
        _reap(proc)
    assert _hidden(out) == []
    assert (out / name / "zarr.json" if name.endswith(".zarr") else out / name).exists()


@pytest.mark.parametrize("name", ["r.zarr", "r.npz"])
def test_a_killed_writer_s_temporary_is_removed_even_with_a_child_still_running(
    tmp_path, caplog, name
):
    """SIGKILL: the kernel releases the writer's lock; a child it forked does not keep it."""
    out = tmp_path / "out"
    out.mkdir()
    proc, go = _writer(tmp_path, out / name, "fork")
    proc.kill()
    proc.wait()
    try:
        left = _hidden(out)
        tmp = [n for n in left if ".quash-tmp-" in n]
        assert len(left) == 2 and len(tmp) == 1 and any(".quash-lck-" in n for n in left), left
        with caplog.at_level(logging.INFO, "quash_plugins"):
            assert atomic.remove_stale(out / name) == [out / tmp[0]]
    finally:
        go.touch()  # the forked child ends
    assert f"quash process {proc.pid}" in caplog.text
    assert _hidden(out) == []


def test_a_store_moved_aside_is_put_back_only_once_its_writer_is_gone(tmp_path, monkeypatch):
    """Between the two renames of a swap the output is missing; a writer that runs still
    holds its lock, so its store moved aside is not put back under it."""
    out = tmp_path / "out"
    out.mkdir()
    store = out / "r.zarr"
    store.mkdir()
    (store / "zarr.json").write_text("previous")
    monkeypatch.setattr(_atomic_stale, "_process_gone", lambda pid: True)
    proc, go = _writer(tmp_path, store, "aside")
    try:
        assert not store.exists()
        before = _hidden(out)
        assert atomic.remove_stale(store) == []
        assert not store.exists() and _hidden(out) == before
        _let_finish(proc, go)
    finally:
        _reap(proc)
    assert (store / "zarr.json").read_text() == "new" and _hidden(out) == []
    # the same writer killed there: its lock is free, the previous store comes back
    monkeypatch.undo()
    go.unlink()
    proc, go = _writer(tmp_path, store, "aside")
    proc.kill()
    proc.wait()
    assert not store.exists()
    half_made = [n for n in _hidden(out) if ".quash-tmp-" in n]  # its new store
    assert [p.name for p in atomic.remove_stale(store)] == half_made
    assert (store / "zarr.json").read_text() == "new" and _hidden(out) == []
