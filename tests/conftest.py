"""Shared test set-up: an isolated cache, no network, and small synthetic worlds."""

from __future__ import annotations

import os

import numpy as np
import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")


@pytest.fixture(autouse=True)
def _isolated_cache(tmp_path_factory, monkeypatch):
    """Every test gets its own empty QuASH cache directory (never the user's)."""
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path_factory.mktemp("quash-cache")))


WORDS = [
    "chair",
    "sofa",
    "table",
    "lamp",
    "other",
    "background",
    "nothing",
    "armchair",
    "couch",
    "desk",
]


@pytest.fixture(autouse=True)
def _package_logging_restored():
    """``main()`` routes the package's logging to its own stderr handler and stops it
    propagating, and ``-q`` silences progress; restore both after each test, so that
    ``caplog`` in a later test of the same process still sees the package's records."""
    import logging

    from quash_plugins.core import progress

    logger = logging.getLogger("quash_plugins")
    handlers, level, propagate = logger.handlers[:], logger.level, logger.propagate
    quiet = progress.QUIET  # main(["-q", ...]) silences progress for the process
    yield
    logger.handlers[:] = handlers
    logger.setLevel(level)
    logger.propagate = propagate
    progress.QUIET = quiet


@pytest.fixture(autouse=True)
def _no_plugin_left_registered():
    """A test that registers a plugin in the process (``registry.register``) removes it
    again: one left behind shows up in every later test's plugin lists (it once made the
    docs test of the built-in plugins fail, depending on the order tests ran in). The
    registrations are restored, and the test that left one fails, naming it."""
    from quash_plugins.core import registry

    before = {kind: list(infos) for kind, infos in registry._manual.items()}
    yield
    left = {
        kind: [f"{i.name} ({i.dist})" for i in infos if i not in before.get(kind, [])]
        for kind, infos in registry._manual.items()
    }
    registry._manual.update(before)
    left = {kind: names for kind, names in left.items() if names}
    if left:
        pytest.fail(f"the test left plugins registered: {left}; unregister them")


@pytest.fixture
def no_vlmaps(monkeypatch):
    """As on a machine without VLMaps (``_no_vlmaps.hide_vlmaps``)."""
    from _no_vlmaps import hide_vlmaps

    from quash_plugins.core import once

    hide_vlmaps(monkeypatch)
    yield
    once.forget("no-vlmaps")


@pytest.fixture
def tiny_world(tmp_path):
    """A 16-d text table and a 600-item NPZ map whose items sit near their label's word.

    Returns a dict with paths and the arrays used to build them, so tests can compute
    expectations independently.
    """
    from quash_plugins.adapters import write_npz_map
    from quash_plugins.core.types import LatentMap

    rng = np.random.default_rng(42)
    T = rng.normal(size=(len(WORDS), 16)).astype(np.float32)
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    table = tmp_path / "text.npz"
    np.savez(table, texts=np.asarray(WORDS), embeddings=T)
    label_names = ["chair", "sofa", "table"]
    labels = rng.integers(0, 3, size=600)
    E = T[labels] + 0.25 * rng.normal(size=(600, 16))
    E = (E / np.linalg.norm(E, axis=1, keepdims=True)).astype(np.float32)
    positions = rng.uniform(0, 5, size=(600, 3)).astype(np.float32)
    map_path = write_npz_map(
        LatentMap(E, positions=positions, labels=labels, label_names=label_names),
        tmp_path / "map.npz",
    )
    config = tmp_path / "contrast.yaml"
    config.write_text(
        "name: vlmaps-contrast\n"
        f"encoder: {{name: table, file: {table.name}}}\n"
        "heuristic: none\n"
        "negatives: [other, background, nothing]\n"
        "classifier: contrast\n"
    )
    return {
        "dir": tmp_path,
        "table": table,
        "map": map_path,
        "config": config,
        "T": T,
        "E": E,
        "labels": labels,
        "label_names": label_names,
        "words": WORDS,
    }


@pytest.fixture(scope="session")
def minilm_scene(tmp_path_factory):
    """A small ``quash make-scene`` voxel map (2 rooms, 0.2 m voxels, grid and label list)
    embedded with the offline MiniLM encoder, and its taxonomy beside it; built once.

    Returns the map's path. For configs that use the map's topology and label list (the
    shipped ``demo:quash-labels``: refinement and the presence check).
    """
    pytest.importorskip("sentence_transformers")
    from quash_plugins.cli.main import main

    out = tmp_path_factory.mktemp("minilm-scene") / "scene.npz"
    args = ["make-scene", str(out), "--rooms", "2", "--voxel-size", "0.2", "--no-cache"]
    assert main(args) == 0
    return out
