"""The proxy scene: deterministic, disjoint names, class proportions, metres."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins.demo.classes import ABSENT, CLASSES, check_disjoint
from quash_plugins.demo.scene import SceneOptions, make_scene, write_scene
from quash_plugins.encoders import TableEncoder

OPTS = SceneOptions(rooms=2, voxel_size=0.2, room_size=4.0, extra_objects=1)


@pytest.fixture(scope="module")
def encoder():
    return TableEncoder(table=table_for({n for c in CLASSES for n in c.appearance}))


def test_names_are_disjoint():
    check_disjoint()
    appearance = {n for c in CLASSES for n in c.appearance}
    language = {n for c in CLASSES for n in c.language} | {n for v in ABSENT.values() for n in v}
    assert not appearance & language
    assert 28 <= len(CLASSES) <= 36


def test_deterministic_given_seed(encoder):
    a, b = make_scene(encoder, OPTS), make_scene(encoder, OPTS)
    assert np.array_equal(a.map.embeddings, b.map.embeddings)
    assert np.array_equal(a.map.labels, b.map.labels)
    c = make_scene(encoder, SceneOptions(**{**OPTS.__dict__, "seed": 1}))
    assert c.map.n != a.map.n or not np.array_equal(c.map.embeddings, a.map.embeddings)


def test_structure_dominates_and_units_are_metres(encoder):
    s = make_scene(encoder, OPTS)
    names = s.map.label_names
    counts = np.bincount(s.map.labels, minlength=len(names))
    structure = sum(counts[names.index(n)] for n in ("floor", "wall", "ceiling"))
    assert structure / counts.sum() > 0.5
    assert (counts > 0).sum() >= 12  # many classes present
    pos = s.map.positions
    extent = pos.max(0) - pos.min(0)
    assert extent[0] == pytest.approx(OPTS.rooms * OPTS.room_size, abs=OPTS.voxel_size)
    assert extent[2] == pytest.approx(OPTS.room_height, abs=OPTS.voxel_size)
    assert np.allclose(pos, s.map.grid_index * OPTS.voxel_size, atol=1e-5)
    norms = np.linalg.norm(s.map.embeddings, axis=1)
    assert np.allclose(norms, 1.0, atol=1e-4)
    # per-class colours: each class's colours scatter around one base colour
    chair = s.map.colors[s.map.labels == names.index("wall")].astype(float)
    assert chair.std(axis=0).max() < 15


def test_embeddings_come_from_appearance_names(encoder):
    opts = SceneOptions(
        **{
            **OPTS.__dict__,
            "noise": 0.0,
            "modality_offset": 0.0,
            "confusion": 0.0,
            "boundary_blend": 0.0,
        }
    )
    s = make_scene(encoder, opts)
    wall = CLASSES[[c.label for c in CLASSES].index("wall")]
    A = encoder.encode_text(list(wall.appearance))
    E = s.map.embeddings[s.map.labels == s.map.label_names.index("wall")]
    # a normalised non-negative mix of the wall's names lies in their span
    coef, *_ = np.linalg.lstsq(A.T, E.T, rcond=None)
    assert np.allclose(A.T @ coef, E.T, atol=1e-4)


def test_write_scene(tmp_path, encoder):
    s = make_scene(encoder, OPTS)
    paths = write_scene(s, tmp_path / "scene.npz", OPTS)
    with np.load(paths["map"]) as z:
        assert str(z["kind"]) == "voxels"
        assert {"labels", "label_names", "grid_index", "voxel_size", "positions"} <= set(z)
    tax = yaml.safe_load(paths["taxonomy"].read_text())
    appearance = {n for c in CLASSES for n in c.appearance}
    assert not appearance & {n for v in tax.values() for n in v}
    assert set(ABSENT) <= set(tax)


def test_shipped_demo_taxonomy_matches_generator():
    from importlib import resources

    text = resources.files("quash_plugins.data").joinpath("configs/demo-taxonomy.yaml")
    tax = yaml.safe_load(text.read_text())
    expected = {c.label: list(c.language) for c in CLASSES}
    expected.update({k: list(v) for k, v in ABSENT.items()})
    assert tax == expected
