"""The docs' code runs, and the generated config reference is current."""

from __future__ import annotations

import re
from pathlib import Path

from quash_plugins.core import registry
from quash_plugins.core.config import config_reference

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _python_blocks(md: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", md, flags=re.S)


def test_plugin_guide_code_runs(capsys):
    blocks = _python_blocks((DOCS / "plugins.md").read_text())
    assert len(blocks) >= 4
    namespace: dict = {"__name__": "plugin_guide"}
    try:
        for block in blocks:
            exec(compile(block, "docs/plugins.md", "exec"), namespace)
    finally:
        registry.unregister("encoders", "bag-of-words")
    assert "bag-of-words" in capsys.readouterr().out


def test_config_reference_is_current():
    text = (DOCS / "config.md").read_text()
    assert config_reference() in text, (
        "regenerate docs/config.md: python -m quash_plugins.core.config"
    )
