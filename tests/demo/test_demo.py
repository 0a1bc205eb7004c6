"""quash demo end to end on the tiny scene with the shipped configs (real MiniLM)."""

from __future__ import annotations

import json

import pytest

from quash_plugins.cli.main import main
from quash_plugins.demo.runner import cache_root, demo_config_paths


def test_demo_configs_ship_as_package_data():
    paths = demo_config_paths()
    assert len(paths) >= 5 and all(p.exists() for p in paths)


@pytest.mark.slow
def test_demo_tiny_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--tiny", "--out", str(out)]) == 0
    for name in ("demo.md", "demo.json", "demo.png", "demo.rrd"):
        assert (out / name).stat().st_size > 0, name
    data = json.loads((out / "demo.json").read_text())
    names = [c["name"] for c in data["configs"]]
    assert names[:4] == ["vlmaps", "conceptfusion", "lerf", "quash-taxonomy"]
    assert "| quash-taxonomy |" in capsys.readouterr().out
    # the scene is cached under $QUASH_CACHE_DIR/demo (set per test by conftest)
    assert list(cache_root().glob("scene-v*-tiny-seed0-*.npz"))
