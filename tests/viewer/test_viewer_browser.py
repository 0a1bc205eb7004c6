"""A real browser: ``quash query --serve-web`` opened in headless Chromium.

The test drives Chromium through the DevTools protocol (tornado's websocket client).
It proves that the web viewer loaded *our* recording, not just that a page answered:
it asks the running viewer for its active recording (``WebHandle.save_recording()``,
the viewer's own RRD encoder), reads those bytes back with ``rerun.chunk.RrdReader``
and checks the entity paths and mask counts. It then takes a screenshot and checks
that the highlighted matches are drawn.

Set ``QUASH_UPDATE_SCREENSHOT=1`` to store the screenshot as docs/images/rerun-viewer.png.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")
pytest.importorskip("tornado")

CHROMIUM = "/usr/bin/chromium"
REPO = Path(__file__).resolve().parents[2]

pytestmark = [
    pytest.mark.browser,
    pytest.mark.slow,
    pytest.mark.skipif(
        not Path(CHROMIUM).exists(), reason=f"headless Chromium not found at {CHROMIUM}"
    ),
]

#: JS: the active recording as base64 RRD, or null while none is loaded.
SAVE_RECORDING_JS = """
(() => {
  const h = window._handle;
  if (!h) return null;
  let bytes;
  try { bytes = h.save_recording(); } catch (e) { return null; }
  let s = "";
  for (let i = 0; i < bytes.length; i += 0x8000) {
    s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  }
  return btoa(s);
})()
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Lines:
    """Collect a pipe's lines in a thread so the child never blocks on a full pipe."""

    def __init__(self, pipe) -> None:
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._pump, args=(pipe,), daemon=True)
        self._t.start()

    def _pump(self, pipe) -> None:
        for line in iter(pipe.readline, ""):
            self.lines.append(line)

    def wait_for(self, pattern: str, timeout: float, proc: subprocess.Popen) -> re.Match:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for line in list(self.lines):
                m = re.search(pattern, line)
                if m:
                    return m
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"no line matching {pattern!r}; got:\n{''.join(self.lines)}")

    def text(self) -> str:
        self._t.join(timeout=5)
        return "".join(self.lines)


class DevTools:
    """A minimal Chrome DevTools protocol client for one page."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.next_id = 0

    async def call(self, method: str, **params):
        self.next_id += 1
        my_id = self.next_id
        await self.ws.write_message(json.dumps({"id": my_id, "method": method, "params": params}))
        while True:
            msg = await asyncio.wait_for(self.ws.read_message(), timeout=60)
            if msg is None:
                raise AssertionError("DevTools connection closed")
            data = json.loads(msg)
            if data.get("id") == my_id:
                if "error" in data:
                    raise AssertionError(f"{method}: {data['error']}")
                return data.get("result", {})

    async def evaluate(self, expression: str):
        res = await self.call("Runtime.evaluate", expression=expression, returnByValue=True)
        return res.get("result", {}).get("value")


def count_mask(path: Path, query: str) -> int | None:
    """Matched items logged for ``query`` in an .rrd, or None when not there (yet)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    if not any(r.application_id == "quash-query" for r in reader.recordings()):
        return None
    total = None
    for chunk in reader.stream().to_chunks():
        if chunk.entity_path.lstrip("/") != f"world/queries/{query}/mask":
            continue
        rb = chunk.to_record_batch()
        if "Boxes3D:centers" in rb.schema.names:
            total = sum(len(v) for v in rb.column("Boxes3D:centers").to_pylist() if v)
    return total


def magenta_pixels(png: bytes) -> int:
    """Pixels close to the mask's highlight colour (magenta) in a screenshot."""
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((r > 120) & (g < 0.35 * r) & (b > 0.5 * r)).sum())


async def drive(url: str, devtools_port: int, tmp: Path, expected: dict[str, int]) -> bytes:
    from tornado.websocket import websocket_connect

    with urllib.request.urlopen(f"http://127.0.0.1:{devtools_port}/json/list", timeout=10) as r:
        pages = [t for t in json.load(r) if t.get("type") == "page"]
    ws = await websocket_connect(pages[0]["webSocketDebuggerUrl"], max_message_size=2**30)
    cdp = DevTools(ws)
    await cdp.call("Page.enable")
    await cdp.call("Page.navigate", url=url)
    deadline = time.monotonic() + 240
    got: dict[str, int | None] = {}
    while time.monotonic() < deadline:
        b64 = await cdp.evaluate(SAVE_RECORDING_JS)
        if b64:
            rrd = tmp / "from-browser.rrd"
            rrd.write_bytes(base64.b64decode(b64))
            got = {q: count_mask(rrd, q) for q in expected}
            if got == expected:
                break
        await asyncio.sleep(1.0)
    else:
        state = await cdp.evaluate("document.getElementById('center_text').innerText")
        raise AssertionError(f"viewer never showed our recording; last {got}; page: {state!r}")
    # The data is in; give the renderer a moment, then look at the pixels.
    png = b""
    for _ in range(30):
        await asyncio.sleep(1.0)
        shot = await cdp.call("Page.captureScreenshot", format="png")
        png = base64.b64decode(shot["data"])
        if magenta_pixels(png) > 50:
            break
    ws.close()
    return png


def test_serve_web_in_headless_chromium(tmp_path):
    from _viewer_maps import voxel_map, write_table_config

    from quash_plugins.adapters import write_npz_map

    lmap = voxel_map(shape=(12, 10, 4), colors="gray")  # only the matches are magenta
    map_path = write_npz_map(tmp_path / "map.npz", lmap)
    cfg = write_table_config(tmp_path)
    expected = {"chair": int((lmap.labels == 0).sum()), "sofa": int((lmap.labels == 1).sum())}
    web, grpc = free_port(), free_port()
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    cli = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from quash_plugins.cli.main import main; raise SystemExit(main())",
            "query",
            str(map_path),
            "chair",
            "sofa",
            "-c",
            str(cfg),
            "--serve-web",
            "--web-port",
            str(web),
            "--grpc-port",
            str(grpc),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    cli_err, cli_out = Lines(cli.stderr), Lines(cli.stdout)
    browser = None
    try:
        url = cli_err.wait_for(r"Serving the Rerun web viewer at (\S+)", 120, cli).group(1)
        assert url.startswith(f"http://127.0.0.1:{web}/?url=")
        profile = tmp_path / "chromium-profile"
        browser = subprocess.Popen(
            [
                CHROMIUM,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
                "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader",
                f"--user-data-dir={profile}",
                "--window-size=1600,900",
                "--remote-debugging-address=127.0.0.1",
                "--remote-debugging-port=0",
                "about:blank",
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        b_err = Lines(browser.stderr)
        port = int(
            b_err.wait_for(r"DevTools listening on ws://127\.0\.0\.1:(\d+)/", 60, browser).group(1)
        )
        png = asyncio.run(drive(url, port, tmp_path, expected))
        assert png.startswith(b"\x89PNG")
        assert magenta_pixels(png) > 50, "the matched voxels are not drawn"
        if os.environ.get("QUASH_UPDATE_SCREENSHOT") == "1":
            target = REPO / "docs" / "images" / "rerun-viewer.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(png)
        # Ctrl-C stops serving; the command then finishes normally.
        cli.send_signal(signal.SIGINT)
        assert cli.wait(timeout=60) == 0, cli_err.text()
        assert "stopped serving" in cli_err.text()
        assert "chair" in cli_out.text()
    finally:
        for proc in (browser, cli):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait(timeout=30)
        shutil.rmtree(tmp_path / "chromium-profile", ignore_errors=True)
