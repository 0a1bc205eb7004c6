"""A real browser: ``quash query --serve-web`` opened in headless Chromium.

The test drives Chromium through the DevTools protocol (tornado's websocket client).
It proves that the web viewer loaded *our* recording, not just that a page answered:
it asks the running viewer for its active recording (``WebHandle.save_recording()``,
the viewer's own RRD encoder), reads those bytes back with ``rerun.chunk.RrdReader``
and checks the entity paths and mask counts. It then takes a screenshot and checks
that the highlighted matches are drawn.

A second test opens ``quash demo --serve-web`` the same way and checks that the rooms and
the matches, coloured by outcome against the scene's labels, are in view. Set
``QUASH_UPDATE_SCREENSHOT=1`` to run it on the full demo and store its screenshot as
docs/images/rerun-demo.png.
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")
pytest.importorskip("tornado")

from _procs import Lines, free_port  # noqa: E402

from quash_plugins.viewer import MATCH_COLOR  # noqa: E402

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


def count_matches(path: Path, config: str, app_id: str = "quash-query") -> dict[int, int]:
    """Matched items logged per query step for ``config`` in an .rrd ({} while absent)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    if not any(r.application_id == app_id for r in reader.recordings()):
        return {}
    counts: dict[int, int] = {}
    for chunk in reader.stream().to_chunks():
        if chunk.entity_path.lstrip("/") != f"world/matches/{config}":
            continue
        rb = chunk.to_record_batch()
        if "Boxes3D:centers" in rb.schema.names and "query" in rb.schema.names:
            for t, v in zip(
                rb.column("query").to_pylist(), rb.column("Boxes3D:centers").to_pylist()
            ):
                counts[t] = len(v or [])
    return counts


def magenta_pixels(png: bytes) -> int:
    """Pixels close to the mask's highlight colour (magenta) in a screenshot."""
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    return int(((r > 120) & (g < 0.35 * r) & (b > 0.5 * r)).sum())


#: The outcome colours of ``quash eval --rrd`` and ``quash demo`` (Okabe-Ito), spelled here
#: rather than read from the package: true positives, false positives, false negatives.
OUTCOMES = {"tp": (0, 114, 178), "fp": (213, 94, 0), "fn": (240, 228, 66)}


def outcome_pixels(img: np.ndarray) -> dict[str, int]:
    """Pixels of each outcome colour (every channel within 20 of it) in an ``(H, W, 3)``
    image. The demo scene's own colours are farther from them: its books (60, 100, 200),
    lamps (250, 220, 100), cushions (240, 160, 60) and chairs (200, 60, 60), +-12."""
    return {
        k: int((np.abs(img - np.array(rgb)).max(axis=-1) <= 20).sum())
        for k, rgb in OUTCOMES.items()
    }


def match_colours(path: Path) -> set[tuple[int, int, int]]:
    """Every colour the matches (``world/matches/*``) are drawn in, in an .rrd."""
    from rerun.chunk import RrdReader

    out = set()
    for chunk in RrdReader(path).stream().to_chunks():
        if not chunk.entity_path.lstrip("/").startswith("world/matches/"):
            continue
        rb = chunk.to_record_batch()
        for col in ("Boxes3D:colors", "Points3D:colors"):
            if col in rb.schema.names:
                for packed in rb.column(col).to_pylist():
                    out |= {
                        ((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c in packed or []
                    }
    return out


def logged_steps(path: Path) -> dict[str, set]:
    """``{entity: query steps}`` of the matches, documents and summary in an .rrd."""
    from rerun.chunk import RrdReader

    out: dict[str, set] = {}
    try:
        chunks = list(RrdReader(path).stream().to_chunks())
    except ValueError:  # no recording store yet (only the blueprint has arrived)
        return out
    for chunk in chunks:
        entity = chunk.entity_path.lstrip("/")
        if not entity.startswith(("world/matches/", "queries/", "summary")):
            continue
        rb = chunk.to_record_batch()
        steps = rb.column("query").to_pylist() if "query" in rb.schema.names else [None]
        out.setdefault(entity, set()).update(steps)
    return out


def rooms_and_matches(png: bytes) -> dict[str, float]:
    """What the main 3D view (the left 58 % of the page, below the tab bar) shows.

    ``coverage``: share of its pixels that are not the viewer's plain background;
    ``colours``: distinct colours (16 levels per channel) covering 0.2 % of it or more,
    i.e. the map's own colours, not one grey slab; ``tp``, ``fp``, ``fn``: matched and
    missed voxels coloured by outcome (:func:`outcome_pixels`).
    """
    import io

    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    h, w, _ = img.shape
    view = img[int(0.12 * h) : int(0.88 * h), : int(0.58 * w)]
    pixels = view.reshape(-1, 3)
    light = (pixels.min(axis=1) > 235) & (np.ptp(pixels, axis=1) < 10)  # background
    levels = (pixels[~light] // 16).astype(np.int64)
    keys, counts = np.unique(
        levels[:, 0] * 256 + levels[:, 1] * 16 + levels[:, 2], return_counts=True
    )
    return {
        "coverage": float((~light).mean()),
        "colours": int((counts >= 0.002 * len(pixels)).sum()),
        **outcome_pixels(view),
    }


def start_chromium(tmp_path: Path) -> tuple[subprocess.Popen, int]:
    """Headless Chromium with a fresh profile; returns it and its DevTools port."""
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
            "--window-size=1600,1000",
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
    return browser, port


def start_cli(args: list[str], cwd: Path, **env: str) -> tuple[subprocess.Popen, Lines, Lines]:
    full_env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200", **env}
    cli = subprocess.Popen(
        [sys.executable, "-c", "from quash_plugins.cli.main import main; raise SystemExit(main())"]
        + args,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=full_env,
        cwd=cwd,
    )
    return cli, Lines(cli.stderr), Lines(cli.stdout)


async def drive(
    url: str, devtools_port: int, tmp: Path, loaded, good_enough, wait_s: float = 300
) -> bytes:
    """Open ``url``; poll the viewer's recording until ``loaded(rrd_path)``; then take
    screenshots until ``good_enough(png)`` (or 30 s) and return the last one."""
    from tornado.websocket import websocket_connect

    with urllib.request.urlopen(f"http://127.0.0.1:{devtools_port}/json/list", timeout=10) as r:
        pages = [t for t in json.load(r) if t.get("type") == "page"]
    ws = await websocket_connect(pages[0]["webSocketDebuggerUrl"], max_message_size=2**30)
    cdp = DevTools(ws)
    await cdp.call("Page.enable")
    await cdp.call("Page.navigate", url=url)
    deadline = time.monotonic() + wait_s
    last = None
    while time.monotonic() < deadline:
        b64 = await cdp.evaluate(SAVE_RECORDING_JS)
        if b64:
            rrd = tmp / "from-browser.rrd"
            rrd.write_bytes(base64.b64decode(b64))
            last = loaded(rrd)
            if last is True:
                break
        await asyncio.sleep(1.0)
    else:
        state = await cdp.evaluate("document.getElementById('center_text').innerText")
        raise AssertionError(f"viewer never showed our recording; last {last}; page: {state!r}")
    # The data is in; give the renderer a moment, then look at the pixels.
    png = b""
    for _ in range(30):
        await asyncio.sleep(1.0)
        shot = await cdp.call("Page.captureScreenshot", format="png")
        png = base64.b64decode(shot["data"])
        if good_enough(png):
            break
    ws.close()
    return png


def stop(*procs: subprocess.Popen | None) -> None:
    for proc in procs:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait(timeout=30)


def test_serve_web_in_headless_chromium(tmp_path):
    from _viewer_maps import voxel_map, write_table_config

    from quash_plugins.adapters import write_npz_map

    lmap = voxel_map(shape=(12, 10, 4), colors="gray")  # only the matches are magenta
    map_path = write_npz_map(lmap, tmp_path / "map.npz")
    cfg = write_table_config(tmp_path)
    # Query 0 is "chair", query 1 "sofa" (the config is named table-contrast).
    expected = {0: int((lmap.labels == 0).sum()), 1: int((lmap.labels == 1).sum())}
    web, grpc = free_port(), free_port()
    cli, cli_err, cli_out = start_cli(
        ["query", str(map_path), "chair", "sofa", "-c", str(cfg), "--serve-web"]
        + ["--web-port", str(web), "--grpc-port", str(grpc)],
        tmp_path,
    )
    browser = None
    try:
        cli_err.wait_for("Serving the Rerun web viewer", 120, cli)  # all logged
        url = cli_err.wait_for(r"Rerun web viewer: (\S+)", 1, cli).group(1)  # said once
        assert url.startswith(f"http://127.0.0.1:{web}/?url=")
        browser, port = start_chromium(tmp_path)
        png = asyncio.run(
            drive(
                url,
                port,
                tmp_path,
                loaded=lambda rrd: count_matches(rrd, "table_contrast") == expected or None,
                good_enough=lambda png: magenta_pixels(png) > 50,
            )
        )
        assert png.startswith(b"\x89PNG")
        assert magenta_pixels(png) > 50, "the matched voxels are not drawn"
        # Ctrl-C stops serving; the command then finishes normally.
        cli.send_signal(signal.SIGINT)
        assert cli.wait(timeout=60) == 0, cli_err.text()
        assert "stopped serving" in cli_err.text()
        assert "chair" in cli_out.text()
    finally:
        stop(browser, cli)
        shutil.rmtree(tmp_path / "chromium-profile", ignore_errors=True)


def test_demo_in_headless_chromium_shows_the_rooms_and_the_matches(tmp_path):
    """``quash demo --serve-web`` as a user opens it: the tab of the best method, the
    rooms seen from above (ceiling hidden), the first query's matches coloured by outcome
    as ``quash eval --rrd`` colours them (they were magenta): the true positives blue
    in view, and no magenta in the recording the viewer holds (the scene has no
    unlabelled item, so every match is scored).

    The tiny scene by default; the full demo with ``QUASH_DEMO_FULL=1`` or when
    refreshing the docs' screenshot (``QUASH_UPDATE_SCREENSHOT=1``:
    docs/images/rerun-demo.png).
    """
    update = os.environ.get("QUASH_UPDATE_SCREENSHOT") == "1"
    full = update or os.environ.get("QUASH_DEMO_FULL") == "1"
    web, grpc = free_port(), free_port()
    out = tmp_path / "demo"
    args = ["demo", "--serve-web", "--web-port", str(web), "--grpc-port", str(grpc)]
    args += ["--out", str(out)] + ([] if full else ["--tiny"])
    cli, cli_err, cli_out = start_cli(args, tmp_path)
    browser = None
    try:
        cli_err.wait_for("Serving the Rerun web viewer", 600, cli)  # all logged
        url = cli_err.wait_for(r"Rerun web viewer: (\S+)", 1, cli).group(1)  # said once
        assert url.startswith(f"http://127.0.0.1:{web}/?url=")
        want = logged_steps(out / "demo.rrd")
        assert any(p.startswith("world/matches/") for p in want) and "summary" in want

        def loaded(rrd: Path):
            got = logged_steps(rrd)
            missing = {p: t - got.get(p, set()) for p, t in want.items()}
            return True if not any(missing.values()) else len(got)

        def good(png: bytes) -> bool:
            seen = rooms_and_matches(png)
            return seen["tp"] > 50 and seen["colours"] >= 8

        browser, port = start_chromium(tmp_path)
        png = asyncio.run(drive(url, port, tmp_path, loaded, good, wait_s=600))
        if update:
            target = REPO / "docs" / "images" / "rerun-demo.png"
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(png)
        (tmp_path / "screenshot.png").write_bytes(png)  # to look at when this fails
        seen = rooms_and_matches(png)
        assert seen["tp"] > 50, f"the true positives are not drawn blue: {seen}"
        drawn = match_colours(tmp_path / "from-browser.rrd")
        assert set(OUTCOMES.values()) <= drawn, f"not every outcome is drawn: {drawn}"
        assert tuple(MATCH_COLOR) not in drawn, "matches drawn magenta, not by outcome"
        assert seen["coverage"] > 0.08, f"the map is not in view: {seen}"
        assert seen["colours"] >= 8, f"no rooms to see (one grey slab?): {seen}"
        cli.send_signal(signal.SIGINT)
        assert cli.wait(timeout=60) == 0, cli_err.text()
        assert "stopped serving" in cli_err.text()
        assert "quash-taxonomy" in cli_out.text()
    finally:
        stop(browser, cli)
        shutil.rmtree(tmp_path / "chromium-profile", ignore_errors=True)
