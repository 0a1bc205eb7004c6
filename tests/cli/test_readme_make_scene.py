"""README.md's comment on `quash make-scene scene.npz` names every file it writes."""

from __future__ import annotations

import re
from pathlib import Path

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_names_every_file_make_scene_writes(minilm_scene):
    line = next(
        ln for ln in README.read_text().splitlines() if ln.startswith("quash make-scene scene.npz")
    )
    named = {"scene.npz", *re.findall(r"scene\.[\w.-]+\.yaml", line)}
    written = {p.name for p in minilm_scene.parent.iterdir()}
    assert named == written, (named, written)
