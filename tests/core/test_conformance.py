"""Every registered plugin, built-in or third-party, passes the conformance kit."""

from __future__ import annotations

from quash_plugins.testing import parametrize_with_checks


@parametrize_with_checks()
def test_plugin_conformance(check, tmp_path):
    check(tmp_path)
