"""Importing quash_plugins (and listing plugins) must not import heavy libraries."""

from __future__ import annotations

import subprocess
import sys

HEAVY = (
    "torch",
    "rerun",
    "open3d",
    "h5py",
    "dask",
    "zarr",
    "httpx",
    "open_clip",
    "sentence_transformers",
)


def _imported_after(code: str) -> set[str]:
    probe = f"{code}\nimport sys\nprint(','.join(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return {m for m in out.stdout.strip().split(",") if m}


def test_import_is_light():
    assert (
        _imported_after("import quash_plugins; quash_plugins.Quash; quash_plugins.core.registry")
        == set()
    )


def test_listing_plugins_is_light():
    code = "from quash_plugins import registry\nfor k in registry.KINDS: registry.available(k)"
    assert _imported_after(code) == set()


def test_loading_every_plugin_class_is_light():
    code = "from quash_plugins import registry\nregistry.plugins(load=True)"
    assert _imported_after(code) == set()
