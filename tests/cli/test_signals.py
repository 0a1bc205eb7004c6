"""SIGTERM or SIGINT in the middle of a write leaves no hidden temporary file.

A real ``quash convert`` runs in a subprocess on a map whose rows are read slowly; once
its temporary output appears the test sends the signal and checks the exit status, that
the destination was not created and that nothing hidden is left beside it. SIGKILL cannot
be caught: its temporary output is removed by the next write of the same output.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

CHILD = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from quash_plugins.core import registry
    from quash_plugins.core.interfaces import MapAdapter
    from quash_plugins.core.types import LatentMap

    class SlowRows:
        shape, dtype, ndim = (10 * 65536, 8), np.dtype("float32"), 2

        def __getitem__(self, key):
            time.sleep(1.0)
            return np.ones(self.shape, np.float32)[key]

    class SlowAdapter(MapAdapter):
        name = "slow"

        def sniff(self, source):
            return False

        def read(self, source, **options):
            n = SlowRows.shape[0]
            rng = np.random.default_rng(0)
            positions = rng.uniform(0, 1, (n, 3)) if n < 10000 else None  # the viewer's map
            return LatentMap(SlowRows(), positions=positions, source={"path": str(source)})

    registry.register("adapters", "slow", SlowAdapter)
    from quash_plugins.cli.main import main

    src, dst = sys.argv[1], sys.argv[2]
    if dst.endswith(".rrd"):  # a query whose recording is being written
        SlowRows.shape = (2000, 8)
        args = ["query", src, "chair", "-c", sys.argv[3], "--adapter", "slow", "--rrd", dst]
    else:
        args = ["convert", src, dst, "--adapter", "slow"]
    sys.exit(main(["-q", *args]))
    """
)

CONFIG = "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0], other: [0, 1, 0, 0, 0, 0, 0, 0]}}\nnegatives: [other]\ninstances: false\ncache: false\n"


def _hidden(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def _wait_for_temporary(proc, out):
    """Until the child ``proc`` has made its temporary output in ``out`` (at most 60 s)."""
    deadline = time.monotonic() + 60
    while not _hidden(out):
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the temporary output never appeared"
        time.sleep(0.05)


@pytest.mark.parametrize(
    ("sig", "code", "suffix"),
    [
        (signal.SIGTERM, 143, ".npz"),
        (signal.SIGINT, 130, ".npz"),
        (signal.SIGTERM, 143, ".zarr"),
        (signal.SIGINT, 130, ".zarr"),
        (signal.SIGTERM, 143, ".rrd"),
        (signal.SIGINT, 130, ".rrd"),
    ],
)
def test_signal_mid_write_leaves_no_temporary_file(tmp_path, sig, code, suffix):
    if suffix == ".zarr":
        pytest.importorskip("zarr")
    if suffix == ".rrd":
        pytest.importorskip("rerun")
    src = tmp_path / "src.bin"
    src.write_bytes(b"x")
    out = tmp_path / "out"
    out.mkdir()
    dst = out / f"map{suffix}"
    config = tmp_path / "c.yaml"
    config.write_text(CONFIG)
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(src), str(dst), str(config)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        _wait_for_temporary(proc, out)
        time.sleep(0.3)  # well inside the write
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == code, err.decode()
    assert not dst.exists()
    assert _hidden(out) == []


@pytest.mark.parametrize("made", [".quash-tmp-", ".quash-lck-"])
def test_interrupt_right_after_the_temporary_file_is_created(tmp_path, monkeypatch, made):
    """The window that left a 0-byte hidden file: Ctrl-C between creating the temporary
    file (or the lock file its writer holds) and entering the block that removes it."""
    from quash_plugins.core import atomic

    real_open = os.open

    def open_then_interrupt(*args, **kwargs):
        fd = real_open(*args, **kwargs)
        if made not in str(args[0]):
            return fd
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic.os, "open", open_then_interrupt)
    with pytest.raises(KeyboardInterrupt), atomic.atomic_write(tmp_path / "r.npz"):
        pass
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".npz", ".zarr"])
def test_sigkill_mid_write_leaves_a_temporary_output_the_next_write_removes(tmp_path, suffix):
    """SIGKILL cannot be caught: the hidden temporary output stays, and the next write of
    the same output (a real ``quash convert``) removes it, saying so."""
    if suffix == ".zarr":
        pytest.importorskip("zarr")
    import numpy as np

    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    src = tmp_path / "src.bin"
    src.write_bytes(b"x")
    small = write_npz_map(
        LatentMap(np.eye(4, 8, dtype=np.float32), positions=np.zeros((4, 3))),
        tmp_path / "small.npz",
    )
    out = tmp_path / "out"
    out.mkdir()
    dst = out / f"map{suffix}"
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(src), str(dst)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        _wait_for_temporary(proc, out)
        time.sleep(0.3)
        proc.kill()
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    hidden = _hidden(out)  # the temporary output, and the lock file its writer held
    left = [n for n in hidden if ".quash-tmp-" in n]
    assert len(hidden) == 2 and len(left) == 1 and f"-{proc.pid}-" in left[0], hidden
    assert any(".quash-lck-" in n and f"-{proc.pid}-" in n for n in hidden), hidden
    again = subprocess.run(
        [sys.executable, "-m", "quash_plugins.cli.main", "convert", str(small), str(dst)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert again.returncode == 0, again.stderr
    assert f"removed {out / left[0]}" in again.stderr
    assert f"quash process {proc.pid}" in again.stderr
    assert _hidden(out) == []
    assert dst.exists()


def test_ctrl_c_while_the_parser_is_built_is_one_line_and_130(monkeypatch, capsys):
    """Ctrl-C before the command runs (quash imports its commands while it builds its
    parser) used to end in a traceback and death by SIGINT."""
    from quash_plugins.cli import main as cli

    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert cli.main(["plugins"]) == 130
    assert capsys.readouterr().err == "interrupted\n"
