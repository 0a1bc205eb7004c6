"""``--serve-web`` says its URL once: when the viewer is up, so that it can be opened
while the command works. Once everything is logged, one line says that it is still
serving and how to stop, pointing at that URL (it printed the URL a second time, with
"Press Ctrl-C to stop." on a line of its own). A real subprocess, stopped with Ctrl-C.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys

import pytest

pytest.importorskip("rerun")

from _procs import Lines, free_port  # noqa: E402
from _viewer_maps import voxel_map, write_table_config  # noqa: E402

from quash_plugins.viewer import rerun_executable  # noqa: E402

CLI = [sys.executable, "-c", "from quash_plugins.cli.main import main; raise SystemExit(main())"]


@pytest.mark.skipif(rerun_executable() is None, reason="the SDK's rerun executable is missing")
@pytest.mark.parametrize("quiet", [False, True], ids=["default", "quiet"])
def test_serve_web_says_its_url_once(quiet, tmp_path):
    from quash_plugins.adapters import write_npz_map

    map_path = write_npz_map(voxel_map(), tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    web, grpc = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    args = ["query", str(map_path), "chair", "-c", str(cfg), "--serve-web"]
    args += ["--web-port", str(web), "--grpc-port", str(grpc)]
    cli = subprocess.Popen(
        [*CLI, *(["-q"] if quiet else []), *args],
        cwd=tmp_path,
        env={**env, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err, out = Lines(cli.stderr), Lines(cli.stdout)
    try:
        url = err.wait_for(r"^Rerun web viewer: (http://\S+)$", 120, cli).group(1)
        assert url.startswith(f"http://127.0.0.1:{web}/?url=")
        end = err.wait_for(r"^Serving the Rerun web viewer.*$", 120, cli).group(0)
        cli.send_signal(signal.SIGINT)
        assert cli.wait(timeout=60) == 0, err.text()
    finally:
        if cli.poll() is None:
            cli.kill()
            cli.wait(timeout=30)
    said = err.text() + out.text()
    assert said.count(f"127.0.0.1:{web}") == 1, said  # the URL, once
    assert "Ctrl-C" in end and "URL above" in end, end  # still serving; how to stop
    assert re.search(r"(?m)^stopped serving$", err.text()), err.text()
    assert "chair" in out.text()  # the query's table, --quiet or not
