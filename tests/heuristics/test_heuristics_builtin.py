"""Taxonomy, lexicon, adjectives, templates, vocabulary, combine and map-mined negatives."""

from __future__ import annotations

import hashlib
from importlib import resources

import numpy as np
import pytest
import yaml

from quash_plugins.core import registry
from quash_plugins.core.errors import ConfigError, HeuristicError, PluginError
from quash_plugins.core.interfaces import Encoder, ExpansionContext
from quash_plugins.core.types import LatentMap, QuerySet
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine.pipeline import Quash
from quash_plugins.heuristics import add_map_negatives


class HashEncoder(Encoder):
    """Deterministic pseudo-random unit vectors per string (any text works)."""

    name = "hash-test"

    @property
    def dim(self) -> int:
        return 16

    def encode_text(self, texts):
        rows = []
        for t in texts:
            seed = int.from_bytes(hashlib.sha256(t.encode()).digest()[:8], "little")
            v = np.random.default_rng(seed).normal(size=16)
            rows.append(v / np.linalg.norm(v))
        return np.asarray(rows, dtype=np.float32)


def ctx(seed=0, **kw):
    return ExpansionContext(seed=seed, **kw)


def shipped_adjectives():
    text = resources.files("quash_plugins.data").joinpath("adjectives.yaml").read_text()
    return yaml.safe_load(text)


# ---------------------------------------------------------------- adjectives
def test_adjectives_counts_and_distinct_types():
    adj = shipped_adjectives()
    kind_of = {a: k for k, words in adj.items() for a in words}
    assert len(adj) == 7 and len(kind_of) == 44
    h = registry.create("heuristics", "adjectives")
    qs = h.expand("chair", ctx(seed=5))
    pos = qs.positives
    assert pos[0] == "chair"
    singles = [p for p in pos if len(p.split()) == 2]
    doubles = [p for p in pos if len(p.split()) == 3]
    triples = [p for p in pos if len(p.split()) == 4]
    assert sorted(singles) == sorted(f"{a} chair" for a in kind_of)
    assert len(doubles) == 10 and len(triples) == 5
    assert len(pos) == 1 + 44 + 10 + 5 == len(set(pos))
    for phrase in doubles + triples:
        words = phrase.split()[:-1]
        kinds = [kind_of[w] for w in words]
        assert len(set(kinds)) == len(kinds), phrase
        order = list(adj)
        assert kinds == sorted(kinds, key=order.index), phrase  # phrase order = type order
    assert all(n.endswith("other") for n in qs.negatives)
    assert len(qs.negatives) == 60 and qs.negatives[0] == "other"


def test_adjectives_seeded():
    h = registry.create("heuristics", "adjectives")
    a = h.expand("chair", ctx(seed=1))
    b = h.expand("chair", ctx(seed=1))
    c = h.expand("chair", ctx(seed=2))
    assert a.positives == b.positives and a.negatives == b.negatives
    assert a.positives != c.positives


def test_adjectives_custom_file_and_too_many(tmp_path):
    f = tmp_path / "adj.yaml"
    f.write_text("colour: [red, blue]\nmaterial: [wooden]\nage: [old]\n")
    qs = registry.create(
        "heuristics", "adjectives", file=str(f), n_double=5, n_triple=2, negatives=False
    ).expand("lamp", ctx())
    # pairs: red/blue x wooden, red/blue x old, wooden x old = 5; triples: 2
    assert len(qs.positives) == 1 + 4 + 5 + 2
    assert qs.negatives == []
    with pytest.raises(ConfigError, match="only 2 exist"):
        registry.create("heuristics", "adjectives", file=str(f), n_double=5, n_triple=3).expand(
            "x", ctx()
        )


# ---------------------------------------------------------------- lexicon
def test_lexicon_shipped_list_and_seed():
    words = [
        w
        for w in resources.files("quash_plugins.data")
        .joinpath("lexicon.txt")
        .read_text()
        .splitlines()
        if w and not w.startswith("#")
    ]
    assert len(words) >= 2000 and len(set(words)) == len(words)
    h = registry.create("heuristics", "lexicon")
    a = h.expand("chair", ctx(seed=3))
    assert len(a.positives) == 21 and len(a.negatives) == 20
    assert set(a.positives[1:]) <= set(words) and set(a.negatives) <= set(words)
    assert not set(a.positives) & set(a.negatives)
    assert a.positives == h.expand("chair", ctx(seed=3)).positives
    assert a.positives != h.expand("chair", ctx(seed=4)).positives


def test_lexicon_one_side_only(tmp_path):
    f = tmp_path / "w.txt"
    f.write_text("# words\nalpha\nbeta\ngamma\nchair\n")
    qs = registry.create("heuristics", "lexicon", n_synonyms=0, n_antonyms=3, file=str(f)).expand(
        "chair", ctx()
    )
    assert qs.positives == ["chair"] and sorted(qs.negatives) == ["alpha", "beta", "gamma"]


# ---------------------------------------------------------------- taxonomy
TAX = {
    "chair": ["armchair", "dining chair", "office chair", "stool", "recliner"],
    "table": ["desk", "coffee table", "side table"],
    "lamp": ["floor lamp", "desk lamp"],
    "wall": None,
}


def test_taxonomy_sampling_and_seed(tmp_path):
    f = tmp_path / "tax.yaml"
    f.write_text(yaml.safe_dump(TAX))
    h = registry.create("heuristics", "taxonomy", file=str(f), n_synonyms=3, n_antonyms=4)
    qs = h.expand("chair", ctx(seed=1))
    assert qs.positives[0] == "chair" and len(qs.positives) == 4
    assert set(qs.positives[1:]) <= set(TAX["chair"])
    others = {
        "table",
        "desk",
        "coffee table",
        "side table",
        "lamp",
        "floor lamp",
        "desk lamp",
        "wall",
    }
    assert len(qs.negatives) == 4 and set(qs.negatives) <= others
    assert qs.to_dict() == h.expand("chair", ctx(seed=1)).to_dict()
    seeds = {tuple(h.expand("chair", ctx(seed=s)).negatives) for s in range(6)}
    assert len(seeds) > 1
    full = registry.create("heuristics", "taxonomy", file=str(f)).expand("table", ctx())
    assert full.positives == ["table", *TAX["table"]]
    assert set(full.negatives) == {"chair", *TAX["chair"], "lamp", *TAX["lamp"], "wall"}


def test_a_missing_taxonomy_file_names_its_option_and_a_near_file(tmp_path):
    """'Taxonomy file not found: PATH' gave no fix: it now names the option that names
    the file (file, or taxonomy when the path was given there), what to give it, and a
    file beside it with a near name."""
    (tmp_path / "tax.yml").write_text(yaml.safe_dump(TAX))
    with pytest.raises(ConfigError) as info:
        registry.create("heuristics", "taxonomy", file=str(tmp_path / "tax.yaml"))
    text = str(info.value)
    assert text.startswith(f"Taxonomy file not found: {tmp_path / 'tax.yaml'}. ")
    assert f"Did you mean {tmp_path / 'tax.yml'}?" in text
    assert "The heuristic's 'file' option names it: give a YAML file of {label: [sub-class" in text
    with pytest.raises(ConfigError) as info:
        registry.create("heuristics", "taxonomy", taxonomy=str(tmp_path / "none" / "t.yaml"))
    assert "Did you mean" not in str(info.value)
    assert "The heuristic's 'taxonomy' option names it" in str(info.value)


@pytest.mark.parametrize(
    ("make", "kind", "option"),
    [
        (
            lambda f: registry.create("heuristics", "adjectives", file=f),
            "Adjective list",
            "The adjectives heuristic's 'file' option names it: give a YAML file of {type: "
            "[adjective, ...]}",
        ),
        (
            lambda f: registry.create("heuristics", "lexicon", file=f),
            "Lexicon",
            "The lexicon heuristic's 'file' option names it: give a word list",
        ),
        (
            lambda f: registry.create("heuristics", "vocabulary", vocabulary=f),
            "Vocabulary",
            "The heuristic's 'vocabulary' option names it: give a file of names",
        ),
        (
            lambda f: registry.create("heuristics", "auto", vocabulary=f)._vocabulary(),
            "Vocabulary",
            "The heuristic's 'vocabulary' option names it",
        ),
        (
            lambda f: registry.create("heuristics", "label-list", unlisted=f),
            "Vocabulary",
            "The heuristic's 'unlisted' option names it: give a file of names (one a line, or "
            "a YAML list), 'vocabulary' for the shipped vocabulary, or leave it out",
        ),
        (
            lambda f: add_map_negatives(QuerySet("chair", ["chair"], []), None, None, vocabulary=f),
            "Vocabulary",
            "The 'vocabulary' option of map_negatives names it",
        ),
    ],
)
def test_a_missing_word_file_names_its_option_and_a_near_file(tmp_path, make, kind, option):
    """The adjective, lexicon and vocabulary files said only 'FILE not found: PATH' (the
    'unlisted' option's file was called a vocabulary file, naming no option): each now
    names the option that names it, what to give it, and a file beside it with a near
    name."""
    near = tmp_path / "words.yml"
    near.write_text("condition: [new]\nage: [old]\ncolour: [red]\n")
    with pytest.raises(ConfigError) as info:
        make(str(tmp_path / "words.yaml"))
    text = str(info.value)
    assert text.startswith(f"{kind} file not found: {tmp_path / 'words.yaml'}. ")
    assert f"Did you mean {near}? {option}" in text


def test_a_taxonomy_file_holding_a_list_is_shown_the_form_with_its_labels(tmp_path):
    """A plain YAML list of labels said only 'expected a YAML mapping': the form is now
    shown, written with the file's own first labels."""
    f = tmp_path / "labels.yaml"
    f.write_text("- chair\n- coffee table\n- lamp\n")
    with pytest.raises(ConfigError) as info:
        registry.create("heuristics", "label-list", file=str(f))
    assert str(info.value) == (
        f"{f}: expected a YAML mapping {{label: [sub-class, ...]}} for the taxonomy; it holds "
        "a list of 3 labels. Give each label as a key with its list of sub-classes (an empty "
        "list: none), e.g.:\n  chair: [SUB-CLASS, ...]\n  coffee table: []"
    )
    f.write_text("chair\n")
    with pytest.raises(
        ConfigError, match=r"\{label: \[sub-class, \.\.\.\]\} for the taxonomy; got a str"
    ):
        registry.create("heuristics", "taxonomy", file=str(f))


def test_taxonomy_resolves_non_label_through_encoder(caplog):
    table = {
        "chair": [1, 0, 0, 0],
        "table": [0, 1, 0, 0],
        "lamp": [0, 0, 1, 0],
        "wall": [0, 0, 0, 1],
        "seat": [0.9, 0.2, 0.1, 0.0],
    }
    # resolution compares the query with every label *and* sub-class: each sub-class
    # sits on its label's vector here
    table.update({sub: table[label] for label, subs in TAX.items() for sub in subs or []})
    enc = TableEncoder(table=table)
    h = registry.create("heuristics", "taxonomy", taxonomy=TAX)
    caplog.set_level("INFO")
    qs = h.expand("seat", ctx(encoder=enc))
    expected = max(
        ["chair", "table", "lamp", "wall"], key=lambda k: np.dot(table[k], table["seat"])
    )
    assert expected == "chair"
    assert qs.positives[:2] == ["seat", "chair"]
    assert set(qs.positives[2:]) <= set(TAX["chair"])
    assert qs.provenance["resolved"]["to"] == "chair"
    assert qs.provenance["resolved"]["from"] == "seat"
    assert "resolved to label 'chair'" in caplog.text
    with pytest.raises(HeuristicError, match="not a label"):
        h.expand("seat", ctx())  # no encoder
    with pytest.raises(HeuristicError, match="resolve is off"):
        registry.create("heuristics", "taxonomy", taxonomy=TAX, resolve=False).expand(
            "seat", ctx(encoder=enc)
        )


def test_taxonomy_keeps_far_queries_as_their_own_concept():
    table = {
        "chair": [1, 0, 0, 0],
        "table": [0, 1, 0, 0],
        "lamp": [0, 0, 1, 0],
        "wall": [0, 0, 0, 1],
        "elephant": [0.3, 0.1, 0.0, -0.95],
    }
    table.update({sub: table[label] for label, subs in TAX.items() for sub in subs or []})
    enc = TableEncoder(table=table)
    e = np.asarray(table["elephant"]) / np.linalg.norm(table["elephant"])
    best = max(np.dot(e, table[k]) for k in ("chair", "table", "lamp", "wall"))
    assert best < 0.5  # independent check of the premise
    qs = registry.create("heuristics", "taxonomy", taxonomy=TAX).expand(
        "elephant", ctx(encoder=enc)
    )
    assert qs.positives == ["elephant"]
    assert qs.provenance["label"] is None
    every_subclass = {s for subs in TAX.values() for s in subs or []} | set(TAX)
    assert set(qs.negatives) <= every_subclass and qs.negatives
    loose = registry.create("heuristics", "taxonomy", taxonomy=TAX, min_similarity=0.0)
    assert loose.expand("elephant", ctx(encoder=enc)).provenance["label"] == "chair"


def test_taxonomy_from_map_labels():
    h = registry.create("heuristics", "taxonomy")
    qs = h.expand("Chair", ctx(label_names=["chair", "table", "floor"]))
    assert qs.positives == ["Chair", "chair"] and qs.negatives == ["table", "floor"]
    with pytest.raises(HeuristicError, match="no taxonomy"):
        h.expand("chair", ctx())


# ---------------------------------------------------------------- templates
def test_templates_shipped_and_pipeline_uses_them():
    from quash_plugins.core.text import load_templates

    tpl = load_templates("default")
    assert 55 <= len(tpl) <= 70 and all(t.count("{}") == 1 for t in tpl)
    h = registry.create("heuristics", "templates", mode="all")
    qs = h.expand("chair", ctx())
    assert qs.positives == ["chair"] and qs.negatives == []
    enc = HashEncoder()
    q = Quash(enc, heuristic=h, classifier=registry.create("classifiers", "svm-rbf"))
    full = q.expand("chair")
    assert full.provenance["prompt_templates"]["count"] == len(tpl)
    X, y, texts = q.training_set(full)
    n_strings = 1 + len(full.negatives)
    assert X.shape == (n_strings * len(tpl), 16)
    assert texts[0] == tpl[0].format("chair")
    # mean mode: one row per string, equal to the normalised mean of the variants
    qm = Quash(
        enc,
        heuristic=registry.create("heuristics", "templates"),
        classifier=registry.create("classifiers", "svm-rbf"),
    )
    Xm, _, _ = qm.training_set(qm.expand("chair"))
    want = enc.encode_text([t.format("chair") for t in tpl]).mean(axis=0)
    np.testing.assert_allclose(Xm[0], want / np.linalg.norm(want), atol=1e-5)
    # an explicit pipeline setting wins over the heuristic's
    qx = Quash(
        enc,
        heuristic=h,
        prompt_templates={"mode": "mean", "templates": ["a {}."]},
        classifier=registry.create("classifiers", "svm-rbf"),
    )
    assert qx.training_set(qx.expand("chair"))[0].shape[0] == n_strings


def test_templates_file_and_bad_mode(tmp_path):
    f = tmp_path / "t.txt"
    f.write_text("a {} here.\n# comment\nthe {}.\n")
    h = registry.create("heuristics", "templates", templates_file=str(f))
    assert h.prompt_templates["templates"] == ["a {} here.", "the {}."]
    with pytest.raises(ConfigError, match="mode"):
        registry.create("heuristics", "templates", mode="median")


# ---------------------------------------------------------------- combine
def test_combine_takes_each_side_from_its_heuristic():
    h = registry.create(
        "heuristics",
        "combine",
        synonyms={"name": "taxonomy", "params": {"taxonomy": TAX, "n_synonyms": 2}},
        antonyms={"name": "lexicon", "n_synonyms": 0, "n_antonyms": 7},
    )
    qs = h.expand("chair", ctx(seed=2))
    syn = registry.create("heuristics", "taxonomy", taxonomy=TAX, n_synonyms=2).expand(
        "chair", ctx(seed=2)
    )
    ant = registry.create("heuristics", "lexicon", n_synonyms=0, n_antonyms=7).expand(
        "chair", ctx(seed=2)
    )
    assert qs.positives == syn.positives
    assert qs.negatives == [n for n in ant.negatives if n not in syn.positives]
    assert qs.provenance["synonyms"]["heuristic"] == "taxonomy"
    assert qs.provenance["antonyms"]["heuristic"] == "lexicon"
    with pytest.raises(ConfigError, match="both"):
        registry.create("heuristics", "combine", synonyms="none")
    with pytest.raises(PluginError, match="combine.antonyms: Heuristic 'nope' is not registered"):
        registry.create("heuristics", "combine", synonyms="none", antonyms="nope")


# ---------------------------------------------------------------- vocabulary (table encoder)
def _table_vocab_encoder():
    rng = np.random.default_rng(0)
    base = {"chair": rng.normal(size=8), "table": rng.normal(size=8), "lamp": rng.normal(size=8)}
    table = {}
    for k, v in base.items():
        table[k] = v
    noise = lambda s: rng.normal(size=8) * s  # noqa: E731
    table["armchair"] = base["chair"] + noise(0.2)
    table["stool"] = base["chair"] + noise(0.4)
    table["desk"] = base["table"] + noise(0.3)
    table["bench"] = 0.6 * base["chair"] + 0.8 * base["table"]
    table["floor lamp"] = base["lamp"] + noise(0.2)
    for i in range(12):
        table[f"thing{i}"] = rng.normal(size=8)
    return TableEncoder(table={k: list(map(float, v)) for k, v in table.items()}), list(table)


def test_vocabulary_positives_and_negatives_follow_similarity():
    enc, names = _table_vocab_encoder()
    E = enc.encode_text(names)
    q = E[names.index("chair")]
    sims = {n: float(E[i] @ q) for i, n in enumerate(names)}
    h = registry.create(
        "heuristics",
        "vocabulary",
        names=names,
        n_positives=5,
        min_similarity=0.8,
        negative_band=[0.2, 0.6],
        n_near=3,
        n_far=2,
    )
    qs = h.expand("chair", ctx(encoder=enc))
    want_pos = sorted(
        (n for n in names if n != "chair" and sims[n] >= 0.8), key=lambda n: -sims[n]
    )[:5]
    assert qs.positives == ["chair", *want_pos]
    near = sorted(
        (n for n in names if 0.2 <= sims[n] < 0.6 and not n.endswith("chair")),
        key=lambda n: -sims[n],
    )[:3]
    assert qs.negatives[: len(near)] == near
    far = qs.negatives[len(near) :]
    assert len(far) == 2 and all(sims[n] < 0.2 for n in far)
    assert not set(qs.positives) & set(qs.negatives)


def test_vocabulary_needs_encoder_and_valid_band():
    with pytest.raises(HeuristicError, match="encoder"):
        registry.create("heuristics", "vocabulary").expand("chair", ctx())
    with pytest.raises(ConfigError, match="negative_band"):
        registry.create("heuristics", "vocabulary", negative_band=[0.5, 0.2])


def test_shipped_vocabulary_size():
    from quash_plugins.heuristics._vocabulary import load_vocabulary

    names = load_vocabulary()
    assert len(names) >= 1000 and len(set(names)) == len(names)
    assert {"chair", "armchair", "kitchen", "staircase", "doorway"} <= set(names)


# ---------------------------------------------------------------- map-mined negatives
def test_map_negatives_on_synthetic_map():
    d = 6
    eye = np.eye(d, dtype=np.float32)
    names = ["chair", "armchair", "table", "lamp", "rug", "window"]
    table = {
        "chair": eye[0],
        "armchair": 0.95 * eye[0] + 0.3 * eye[5],
        "table": eye[1],
        "lamp": eye[2],
        "rug": eye[3],
        "window": eye[4],
    }
    enc = TableEncoder(table={k: list(map(float, v)) for k, v in table.items()})
    counts = {"chair": 150, "table": 500, "lamp": 300, "rug": 3}
    rng = np.random.default_rng(1)
    rows = [np.repeat(np.asarray(table[k], np.float32)[None], c, 0) for k, c in counts.items()]
    emb = np.concatenate(rows + [np.zeros((47, d), np.float32)])
    emb = (emb + rng.normal(scale=0.05, size=emb.shape).astype(np.float32)) * 3.0
    emb[-47:] = 0  # unobserved
    lmap = LatentMap(emb, normalize=True)
    qs = QuerySet("chair", ["chair", "armchair"], ["other"], {"heuristic": "static"})
    out = add_map_negatives(
        qs, lmap, enc, vocabulary=names, n=5, min_share=0.01, sample=10_000, chunk=128
    )
    observed = sum(counts.values())
    assert out.negatives == ["other", "table", "lamp"]  # rug wins 3/953 < 1%; chair is the query
    prov = out.provenance["map_negatives"]
    assert prov["added"] == ["table", "lamp"]
    assert prov["observed"] == observed
    assert prov["share"]["table"] == pytest.approx(500 / observed, abs=1e-3)
    sub = add_map_negatives(qs, lmap, enc, vocabulary=names, sample=400, n=1, seed=3)
    assert sub.provenance["map_negatives"]["added"] == ["table"]
    assert sub.provenance["map_negatives"]["sampled"] == 400
    with pytest.raises(ConfigError, match="does not accept"):
        add_map_negatives(qs, lmap, enc, vocabulary=names, top=3)


def test_map_negatives_through_pipeline():
    eye = np.eye(4, dtype=np.float32)
    table = {
        "chair": eye[0],
        "table": eye[1],
        "other": eye[2],
        "background": eye[3],
        "nothing": (eye[2] + eye[3]) / 2,
    }
    enc = TableEncoder(table={k: list(map(float, v)) for k, v in table.items()})
    emb = np.concatenate([np.repeat(eye[:1], 10, 0), np.repeat(eye[1:2], 40, 0)])
    q = Quash(enc, map_negatives={"vocabulary": ["chair", "table"], "n": 2})
    qs = q.expand("chair", LatentMap(emb))
    assert "table" in qs.negatives and qs.provenance["map_negatives"]["added"] == ["table"]


# ---------------------------------------------------------------- config and conformance
def test_combine_config_resolves_nested_paths(tmp_path):
    from quash_plugins.core.config import QuashConfig

    sub = tmp_path / "cfg"
    sub.mkdir()
    (sub / "tax.yaml").write_text(yaml.safe_dump(TAX))
    (sub / "method.yaml").write_text(
        "encoder: {name: table, table: {chair: [1, 0], other: [0, 1]}}\n"
        "heuristic:\n  name: combine\n"
        "  synonyms: {name: taxonomy, params: {file: tax.yaml, n_synonyms: 2}}\n"
        "  antonyms: {name: taxonomy, file: tax.yaml}\n"
    )
    q = Quash.from_config(QuashConfig.from_yaml(sub / "method.yaml"))
    qs = q.expand("lamp")
    assert qs.positives == ["lamp", *TAX["lamp"]]
    assert "coffee table" in qs.negatives and "armchair" in qs.negatives


@pytest.mark.parametrize(
    "name,params",
    [
        ("adjectives", {}),
        ("lexicon", {}),
        ("taxonomy", {"taxonomy": TAX}),
        ("taxonomy", {}),
        ("templates", {}),
        ("vocabulary", {}),
        ("combine", {"synonyms": "adjectives", "antonyms": {"name": "lexicon"}}),
    ],
)
def test_conformance_kit(name, params, tmp_path):
    from quash_plugins.testing import check_heuristic

    check_heuristic(registry.create("heuristics", name, **params), tmp_path)
