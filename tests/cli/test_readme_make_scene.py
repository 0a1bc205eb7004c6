"""What README.md, docs/quickstart.md and docs/evaluation.md say `quash make-scene
scene.npz` writes is what it writes: the files beside the map, and the map's arrays."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"


def test_readme_names_every_file_make_scene_writes(minilm_scene):
    line = next(
        ln for ln in README.read_text().splitlines() if ln.startswith("quash make-scene scene.npz")
    )
    named = {"scene.npz", *re.findall(r"scene\.[\w.-]+\.yaml", line)}
    written = {p.name for p in minilm_scene.parent.iterdir()}
    assert named == written, (named, written)


def test_quickstart_names_every_file_make_scene_writes(minilm_scene):
    """The paragraph under the quickstart's `quash make-scene scene.npz` (it once left out
    scene.open-queries.yaml)."""
    text = (ROOT / "docs" / "quickstart.md").read_text(encoding="utf-8")
    paragraph = text[text.index("writes `scene.npz`") :].split("\n\n")[0]
    named = set(re.findall(r"`(scene\.[\w.-]+)`", paragraph))
    written = {p.name for p in minilm_scene.parent.iterdir()}
    assert named == written, (named, written)


def test_evaluation_lists_every_array_of_the_scene(minilm_scene):
    """docs/evaluation.md's `Outputs` of make-scene names every array of OUT.npz (it once
    left out the encoder's name and fingerprint)."""
    text = (ROOT / "docs" / "evaluation.md").read_text(encoding="utf-8")
    outputs = text[text.index("- **Outputs.** `OUT.npz`") :]
    named = set(re.findall(r"`(\w+)(?: = \w+)?`", outputs[: outputs.index("),")]))
    with np.load(minilm_scene) as z:
        assert named == set(z.files), (named, set(z.files))
