"""The proxy scene: deterministic, disjoint names, class proportions, metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from _eval_table import table_for

from quash_plugins.demo.classes import ABSENT, CLASSES, check_disjoint
from quash_plugins.demo.queries import open_queries, plural, with_article
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


# ---------------------------------------------------------------------- harder scenes
def test_default_scene_is_what_it_was_before_the_gap_options(encoder):
    """The digest is the scene of these options from the generator before the gap and
    class-table options existed (main at 6867cad): the defaults change nothing, so the
    demo's cached scenes and every earlier table stay valid."""
    import hashlib

    s = make_scene(encoder, OPTS)
    digest = hashlib.sha256(
        s.map.embeddings.tobytes()
        + s.map.labels.tobytes()
        + s.map.grid_index.astype(np.int64).tobytes()
    ).hexdigest()
    assert digest == "3f7bb83509d9b33dc709968954c8e3a4d2a6902b5b18702c80ca9441231a5d9a"


def test_gap_options_change_the_embeddings_not_the_layout(encoder):
    hard = SceneOptions(**{**OPTS.__dict__, "gap_class": 0.5, "gap_instance": 0.3})
    a, b = make_scene(encoder, OPTS), make_scene(encoder, hard)
    assert np.array_equal(a.map.labels, b.map.labels)
    assert np.array_equal(a.map.grid_index, b.map.grid_index)
    assert np.allclose(np.linalg.norm(b.map.embeddings, axis=1), 1, atol=1e-5)
    # a per-class direction: items of one class move together, so the class means move
    # while the spread around them does not grow much
    wall = a.map.labels == a.map.label_names.index("wall")
    shift = b.map.embeddings[wall].mean(0) - a.map.embeddings[wall].mean(0)
    assert np.linalg.norm(shift) > 0.1
    with pytest.raises(Exception, match="gap_class"):
        make_scene(encoder, SceneOptions(**{**OPTS.__dict__, "gap_class": -1.0}))
    with pytest.raises(Exception, match="classes must be one of a, b"):
        make_scene(encoder, SceneOptions(**{**OPTS.__dict__, "classes": "c"}))


def test_class_table_b_has_other_names_and_no_shared_word():
    from quash_plugins.demo.classes_b import ABSENT_B, CLASSES_B, FREE_TEXT_B, check_b
    from quash_plugins.heuristics._vocabulary import load_vocabulary

    assert check_b({n.lower() for n in load_vocabulary(None)}) == []
    a_labels = {c.label for c in CLASSES}
    b_labels = {c.label for c in CLASSES_B}
    assert len(b_labels - a_labels) >= 12 and len(CLASSES_B) == 34
    assert not set(ABSENT_B) & b_labels
    assert set(FREE_TEXT_B) <= b_labels
    appearance_a = {n for c in CLASSES for n in c.appearance}
    assert not appearance_a & {n for c in CLASSES_B for n in c.appearance}


def test_table_b_scene_and_its_open_queries(tmp_path):
    from quash_plugins.demo.classes_b import ABSENT_B, CLASSES_B, FREE_TEXT_B

    enc = TableEncoder(table=table_for({n for c in CLASSES_B for n in c.appearance}))
    opts = SceneOptions(**{**OPTS.__dict__, "classes": "b"})
    s = make_scene(enc, opts)
    assert s.map.label_names == [c.label for c in CLASSES_B]
    assert set(ABSENT_B) <= set(s.taxonomy)
    present = {s.map.label_names[i] for i in np.unique(s.map.labels)}
    language = {c.label: set(c.language) for c in CLASSES_B}
    # every open query's label is present; sub-class queries are (near forms of) a
    # sub-class of that label
    assert s.open_present and set(s.open_present.values()) <= present
    for text, label in s.open_present.items():
        forms = {f for sub in language[label] for f in (sub, with_article(sub), plural(sub))}
        assert text in forms or text == FREE_TEXT_B.get(label), (text, label)
    assert not set(s.open_absent) & set(s.open_present)
    assert any(a in {n for v in ABSENT_B.values() for n in v} for a in s.open_absent)
    paths = write_scene(s, tmp_path / "b.npz", opts)
    data = yaml.safe_load(paths["open_queries"].read_text())
    assert data["present"] == s.open_present and data["absent"] == s.open_absent


@pytest.mark.parametrize(
    ("name", "article", "many"),
    [
        ("bed", "a bed", "beds"),
        ("armchair", "an armchair", "armchairs"),
        ("end table", "an end table", "end tables"),
        ("unicycle", "a unicycle", "unicycles"),
        ("chest of drawers", "a chest of drawers", "chests of drawers"),
        ("railings", "railings", "railings"),  # already plural: left as it is
        ("dumbbells", "dumbbells", "dumbbells"),
        ("cubby", "a cubby", "cubbies"),
        ("trolley", "a trolley", "trolleys"),
        ("glass", "a glass", "glasses"),
        ("icebox", "an icebox", "iceboxes"),
        ("couch", "a couch", "couches"),
        ("cactus", "a cactus", "cactuses"),
    ],
)
def test_near_forms_are_english(name, article, many):
    assert with_article(name) == article
    assert plural(name) == many


@pytest.mark.parametrize("table", ["a", "b", "benchmarks/classes_c.yaml"])
def test_open_queries_have_no_grammar_slips(table):
    """Every near form the generator can write for tables A, B and C, over many seeds:
    no "a" before a vowel, no doubled plural ("railingses", "chest of drawerses")."""
    import re

    from quash_plugins.demo.class_file import load_class_table
    from quash_plugins.demo.scene import class_set

    cs = load_class_table(table) if table.endswith(".yaml") else class_set(table)
    labels = [c.label for c in cs.classes]
    texts = set()
    for seed in range(40):
        present, absent = open_queries(cs, labels, seed)
        texts |= set(present) | set(absent)
    slips = sorted(
        t
        for t in texts
        if re.match(r"a [aeio]", t)
        or re.search(r"[^aeious]ses$", t)
        or re.match(r"an? [a-z]+[^su]s$", t)  # "a dumbbells"
    )
    assert not slips
    assert not any(t.endswith("ys") and t[-3] not in "aeiou" for t in texts)


@pytest.mark.slow
@pytest.mark.parametrize("table", ["b", "benchmarks/classes_c.yaml"])
def test_tables_b_and_c_classes_are_recognisable_with_minilm(table):
    """The noiseless mean of each class's appearance names is nearest its own label
    (top-2 mean over label and sub-classes): a table-B (or table-C: the held-out third
    table of docs/benchmarks.md) scene's ground truth is one the encoder can see, so a
    hard scene is hard, not wrong."""
    pytest.importorskip("sentence_transformers")
    from quash_plugins.demo.scene import class_set
    from quash_plugins.encoders._sentence_transformers import MiniLMEncoder

    root = Path(__file__).resolve().parents[2]
    cs = class_set(table if len(table) == 1 else str(root / table))
    enc = MiniLMEncoder(device="cpu")
    groups = {c.label: [c.label, *c.language] for c in cs.classes}
    groups.update({k: [k, *v] for k, v in cs.absent.items()})
    wrong = []
    for c in cs.classes:
        m = enc.encode_text(list(c.appearance)).mean(0)
        m /= np.linalg.norm(m)
        score = {}
        for label, names in groups.items():
            sims = np.sort(enc.encode_text(names) @ m)[::-1]
            score[label] = sims[:2].mean()
        best = max(score, key=score.get)
        if best != c.label:
            wrong.append((c.label, best))
    assert not wrong


@pytest.mark.parametrize(
    ("flag", "value", "named"),
    [
        ("--seed", "-5", "seed must be >= 0"),
        ("--extra-objects", "-3", "extra_objects must be >= 0"),
        ("--size-scale", "0", "size_scale must be > 0"),
        ("--noise", "nan", "noise must be a finite number"),
        ("--confusion", "-1", "confusion >= 0"),
    ],
)
def test_make_scene_refuses_bad_options_before_loading_an_encoder(
    tmp_path, capsys, flag, value, named
):
    """A negative seed or object count crashed inside numpy; each is now an error naming
    the option, given before the (slow) encoder is built and before anything is written."""
    from quash_plugins.cli.main import main

    out = tmp_path / "s.npz"
    # an encoder that does not exist: reaching it would give another error
    assert main(["make-scene", str(out), "--encoder", "no-such-encoder", flag, value]) == 1
    assert named in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
    field = flag[2:].replace("-", "_")
    with pytest.raises(Exception, match=named):
        SceneOptions(**{field: type(getattr(OPTS, field))(value)}).validate()
