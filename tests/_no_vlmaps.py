"""Run as on a machine without VLMaps, whatever is installed here."""

from __future__ import annotations

import importlib.util

import pytest


def hide_vlmaps(mp: pytest.MonkeyPatch) -> None:
    """No ``vlmaps`` package can be found while ``mp`` is active, and the once-per-process
    notes about it are forgotten, so the first one is said again."""
    from quash_plugins.core import once

    real = importlib.util.find_spec
    mp.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "vlmaps" else real(name, *a)
    )
    once.forget("no-vlmaps")
