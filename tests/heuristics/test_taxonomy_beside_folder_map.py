"""Where a folder map's taxonomy is looked for is said when none is found there.

A ConceptFusion map is passed as ``saved-map/`` but read from ``saved-map/pointclouds/``,
whose taxonomy is ``saved-map/pointclouds.taxonomy.yaml``. A user who wrote
``saved-map.taxonomy.yaml`` (``MAP.taxonomy.yaml`` beside the path they pass) had it
ignored: the ``taxonomy`` heuristic's error said only "a MAP.taxonomy.yaml beside its
file", and the default config's ``auto`` heuristic fell back to the vocabulary with
nothing said.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from _cf_writers import WORDS, cf_arrays, save_pointclouds, text_table

from quash_plugins.adapters import read_map
from quash_plugins.core import registry
from quash_plugins.core.errors import HeuristicError
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.core.once import forget

TAXONOMY = "chair: [armchair]\nsofa: [couch]\ntable: [desk]\n"


def _saved_map(root: Path) -> Path:
    save_pointclouds(root / "saved-map", **cf_arrays(n=30, d=16, seed=3))
    return root / "saved-map"


def test_the_taxonomy_error_names_the_path_looked_for_and_a_misplaced_one(tmp_path):
    saved = _saved_map(tmp_path)
    expected = saved / "pointclouds.taxonomy.yaml"
    heuristic = registry.create("heuristics", "taxonomy")
    with pytest.raises(HeuristicError) as no_file:
        heuristic.expand("chair", ExpansionContext(map=read_map(saved)))
    assert f"looked for {expected}, not found" in str(no_file.value)
    assert "is not read" not in str(no_file.value)

    misplaced = tmp_path / "saved-map.taxonomy.yaml"
    misplaced.write_text(TAXONOMY)
    with pytest.raises(HeuristicError) as beside_parent:
        heuristic.expand("chair", ExpansionContext(map=read_map(saved)))
    said = str(beside_parent.value)
    assert f"{misplaced}, beside the folder above the map, is not read" in said
    assert f"move it to {expected}" in said

    misplaced.rename(expected)  # where the error said: now it is read
    qs = heuristic.expand("chair", ExpansionContext(map=read_map(saved)))
    assert "armchair" in qs.positives


def test_auto_warns_when_it_falls_back_with_a_taxonomy_beside_the_folder_above(tmp_path, caplog):
    saved = _saved_map(tmp_path)
    (tmp_path / "saved-map.taxonomy.yaml").write_text(TAXONOMY)
    vocabulary = tmp_path / "vocabulary.txt"
    vocabulary.write_text("\n".join(WORDS) + "\n")
    table, _ = text_table(tmp_path, 16)
    encoder = registry.create("encoders", "table", file=str(table))
    auto = registry.create("heuristics", "auto", vocabulary=str(vocabulary))
    forget("auto-vocabulary")
    with caplog.at_level(logging.INFO, logger="quash_plugins"):
        qs = auto.expand("chair", ExpansionContext(encoder=encoder, map=read_map(saved)))
    assert qs.provenance["auto"] == "vocabulary"
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1
    text = warned[0].getMessage()
    assert str(tmp_path / "saved-map.taxonomy.yaml") in text
    assert str(saved / "pointclouds.taxonomy.yaml") in text
