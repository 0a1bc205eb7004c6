"""Sub-category queries resolve to their label; the label list as negatives; the fair
peer's query set; a taxonomy found beside the map."""

from __future__ import annotations

import numpy as np
import pytest
from _eval_table import table_for, vec

from quash_plugins import LatentMap
from quash_plugins.core.errors import HeuristicError
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.encoders import TableEncoder
from quash_plugins.heuristics import LabelListHeuristic, TaxonomyHeuristic, normalise_name
from quash_plugins.heuristics._taxonomy import head_noun

TAX = {"bed": ["bunk bed", "cot"], "sofa": ["futon", "settee"], "chair": ["armchair"]}


def _encoder(extra=None):
    names = {n for k, v in TAX.items() for n in (k, *v)} | {"other", "background", "nothing"}
    return TableEncoder(table={**table_for(names), **(extra or {})})


@pytest.mark.parametrize(
    ("query", "label", "how", "via"),
    [
        ("bed", "bed", "label", "bed"),
        ("Bed", "bed", "label", "bed"),
        ("Bunk bed", "bed", "subclass", "bunk bed"),
        ("Bunk-beds", "bed", "near-subclass", "bunk bed"),
        ("a futon", "sofa", "near-subclass", "futon"),
        ("the settees", "sofa", "near-subclass", "settee"),
        ("beds", "bed", "near-label", "bed"),
    ],
)
def test_subclass_queries_resolve_to_their_label(query, label, how, via):
    h = TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all")
    # no encoder needed: these resolve by name
    res = h.resolve_query(query, ExpansionContext())
    assert (res["to"], res["how"], res["via"]) == (label, how, via)
    qs = h.expand(query, ExpansionContext())
    assert qs.positives[0] == query and label in qs.positives
    assert label not in qs.negatives and via not in qs.negatives
    assert ("resolved" in qs.provenance) == (how != "label")


def test_embedding_resolution_through_a_subclass_and_an_unresolved_query():
    # "somewhere to sleep" sits on "cot"'s vector: resolved to bed *through a sub-class*
    enc = _encoder({"somewhere to sleep": vec("cot"), "an elephant": vec("zzz")})
    h = TaxonomyHeuristic(taxonomy=TAX, min_similarity=0.5)
    ctx = ExpansionContext(encoder=enc)
    r = h.resolve_query("somewhere to sleep", ctx)
    assert (r["to"], r["how"], r["via"]) == ("bed", "embedding", "cot")
    assert r["cosine"] == pytest.approx(1.0, abs=1e-3)
    # the best other label is recorded, for a near tie to be seen (computed here by hand)
    best_other = max(
        (
            (float(np.dot(vec("cot"), vec(n))), k)
            for k, v in TAX.items()
            if k != "bed"
            for n in (k, *v)
        )
    )
    assert r["next"] == best_other[1]
    assert r["next_cosine"] == pytest.approx(best_other[0], abs=1e-4)
    r = h.resolve_query("an elephant", ctx)
    assert r["to"] is None and r["how"] == "none"
    # the record says which label the nearest name belongs to, and quash expand tells it
    near = max(((float(np.dot(vec("zzz"), vec(n))), n, k) for k, v in TAX.items() for n in (k, *v)))
    assert (r["via"], r["nearest"], r["min_similarity"]) == (near[1], near[2], 0.5)
    from quash_plugins.cli.cmd_expand import resolution_line

    line = resolution_line(r)
    assert f"cosine {r['cosine']} < min_similarity 0.5" in line
    assert r["next"] != r["nearest"] and f"next label {r['next']!r}" in line
    assert (f"of label {near[2]!r}" in line) == (near[1] != near[2])
    qs = h.expand("an elephant", ctx)
    assert qs.positives == ["an elephant"] and qs.provenance["label"] is None
    # without an encoder an unknown query is an error naming the fix
    with pytest.raises(HeuristicError, match="not a label or sub-class"):
        h.resolve_query("an elephant", ExpansionContext())


def test_all_antonyms_cover_every_other_label_in_groups():
    qs = TaxonomyHeuristic(taxonomy=TAX, n_antonyms="all").expand("bed", ExpansionContext())
    assert qs.negatives == ["sofa", "futon", "settee", "chair", "armchair"]
    assert qs.provenance["negative_groups"] == [3, 2]
    # the sampled form records no groups, and "all" is the only word accepted
    qs = TaxonomyHeuristic(taxonomy=TAX, n_antonyms=2).expand("bed", ExpansionContext())
    assert len(qs.negatives) == 2 and "negative_groups" not in qs.provenance
    with pytest.raises(Exception, match="'all'"):
        TaxonomyHeuristic(taxonomy=TAX, n_antonyms="every")


def test_normalise_name():
    assert normalise_name("The Bunk-Beds") == "bunk bed"
    assert normalise_name("benches") == "bench" and normalise_name("glass") == "glass"
    assert normalise_name("an Armchair") == "armchair" and normalise_name("cactus") == "cactus"
    assert normalise_name("bodies") == "body" and normalise_name("glasses") == "glass"
    # the head of "X of Y" is X: "chests of drawers" is a chest of drawers, not of drawer
    assert normalise_name("Chests of Drawers") == "chest of drawers"
    assert normalise_name("a chest of drawers") == "chest of drawers"
    assert normalise_name("piles of clothes") == "pile of clothes"
    assert normalise_name("office") == "office"  # "of" only as a word
    assert head_noun("chest of drawers") == "chest" and head_noun("bunk bed") == "bed"


@pytest.mark.parametrize(
    ("plural", "singular"),
    [
        ("shelves", "shelf"),
        ("wall shelves", "wall shelf"),
        ("bookshelves", "bookshelf"),
        ("kitchen knives", "kitchen knife"),
        ("tomatoes", "tomato"),
        ("computer mice", "computer mouse"),
        ("cacti", "cactus"),
        # regular "-ves" and "-oes" keep their "e"
        ("wood stoves", "wood stove"),
        ("gloves", "glove"),
        ("shoes", "shoe"),
        ("olives", "olive"),
    ],
)
def test_irregular_plurals_singularise(plural, singular):
    assert normalise_name(plural) == singular


def test_an_irregular_plural_resolves_to_its_label():
    tax = {"shelf": ["wall shelf", "bookshelf"], "stove": ["wood stove"]}
    h = TaxonomyHeuristic(taxonomy=tax)
    got = {
        q: (r["to"], r["how"])
        for q in ("shelves", "bookshelves", "wood stoves")
        for r in [h.resolve_query(q, ExpansionContext())]
    }
    assert got == {
        "shelves": ("shelf", "near-label"),
        "bookshelves": ("shelf", "near-subclass"),
        "wood stoves": ("stove", "near-subclass"),
    }


def test_a_plural_of_a_compound_resolves_to_its_subclass():
    tax = {"cabinet": ["cupboard", "chest of drawers"], "bed": ["bunk bed"]}
    r = TaxonomyHeuristic(taxonomy=tax).resolve_query("chests of drawers", ExpansionContext())
    assert (r["to"], r["how"], r["via"]) == ("cabinet", "near-subclass", "chest of drawers")


def test_unlisted_reads_the_head_noun_before_of():
    # "treasure chest" shares its head noun with "chest of drawers" (a chest), so it
    # resolves; "drawer" does not (the head of "chest of drawers" is not "drawers")
    tax = {"cabinet": ["cupboard", "chest of drawers"], "bed": ["bunk bed"]}
    enc = TableEncoder(
        table={
            **table_for({"cabinet", "cupboard", "chest of drawers", "bed", "bunk bed"}),
            "treasure chest": vec("cupboard"),
            "drawer": vec("cupboard"),
        }
    )
    ctx = ExpansionContext(encoder=enc)
    h = TaxonomyHeuristic(taxonomy=tax, unlisted=["treasure chest", "drawer"])
    assert h.resolve_query("treasure chest", ctx)["how"] == "embedding"
    assert h.resolve_query("drawers", ctx)["how"] == "unlisted"


def test_label_list_heuristic_is_the_fair_peer_query_set():
    h = LabelListHeuristic(taxonomy=TAX)
    qs = h.expand("bunk beds", ExpansionContext())
    assert qs.positives == ["bed"] and qs.negatives == ["sofa", "chair"]
    assert qs.provenance["resolved"]["how"] == "near-subclass"
    # it resolves exactly as the taxonomy heuristic does
    enc = _encoder({"somewhere to sleep": vec("cot")})
    ctx = ExpansionContext(encoder=enc)
    assert h.expand("somewhere to sleep", ctx).positives == ["bed"]
    assert TaxonomyHeuristic(taxonomy=TAX).resolve_query("somewhere to sleep", ctx)["to"] == "bed"


def test_unlisted_keeps_an_object_name_missing_from_the_list_its_own_concept():
    # "fireplace" sits on "settee"'s vector: by embedding alone it becomes a sofa (the
    # default, which also resolves "couch" -> sofa on a list of bare names)
    enc = _encoder({"fireplace": vec("settee"), "double beds": vec("cot")})
    ctx = ExpansionContext(encoder=enc)
    off = TaxonomyHeuristic(taxonomy=TAX).resolve_query("fireplace", ctx)
    assert (off["to"], off["how"]) == ("sofa", "embedding")
    for names in ("vocabulary", ["Fireplaces"]):  # the shipped vocabulary, or a list
        h = TaxonomyHeuristic(taxonomy=TAX, unlisted=names)
        r = h.resolve_query("a fireplace", ctx)
        assert (r["to"], r["how"], r["via"]) == (None, "unlisted", "fireplace")
        qs = h.expand("a fireplace", ctx)
        assert qs.positives == ["a fireplace"] and {"sofa", "settee"} <= set(qs.negatives)
        # no encoder is needed to keep it its own concept
        assert h.resolve_query("fireplace", ExpansionContext())["how"] == "unlisted"
    # a name that shares its head noun with a label still resolves: a double bed is a bed
    h = TaxonomyHeuristic(taxonomy=TAX, unlisted="vocabulary")
    r = h.resolve_query("double beds", ctx)
    assert (r["to"], r["how"], r["via"]) == ("bed", "embedding", "cot")
    # the fair peer takes the same option, and quash expand says why
    peer = LabelListHeuristic(taxonomy=TAX, unlisted="vocabulary")
    assert peer.expand("fireplace", ctx).positives == ["fireplace"]
    assert LabelListHeuristic(taxonomy=TAX).expand("fireplace", ctx).positives == ["sofa"]
    # the default config's auto heuristic passes the option to its label list
    from quash_plugins.heuristics import AutoHeuristic

    auto = AutoHeuristic(unlisted="vocabulary")
    m = LatentMap(np.eye(3, dtype=np.float32), label_names=["bed", "sofa", "chair"])
    qs = auto.expand("fireplace", ExpansionContext(encoder=enc, label_names=m.label_names, map=m))
    assert qs.positives == ["fireplace"] and qs.provenance["resolved"]["how"] == "unlisted"
    from quash_plugins.cli.cmd_expand import resolution_line

    assert "not in the label list" in resolution_line(r | {"how": "unlisted", "to": None})


def test_without_a_file_the_label_list_is_the_maps_names_and_the_taxonomy_beside_it(tmp_path):
    m = LatentMap(np.eye(3, dtype=np.float32), label_names=["bed", "sofa", "lamp"])
    h = TaxonomyHeuristic(n_antonyms="all")
    qs = h.expand("bed", ExpansionContext(label_names=m.label_names, map=m))
    assert qs.negatives == ["sofa", "lamp"]
    assert qs.provenance["labels_from"] == "the map's label names"
    # a MAP.taxonomy.yaml next to the map's file adds the sub-classes (make-scene writes it)
    (tmp_path / "scene.taxonomy.yaml").write_text(
        "bed: [bunk bed]\nsofa: [futon]\npiano: [grand piano]\n"
    )
    m.source["path"] = str(tmp_path / "scene.npz")
    ctx = ExpansionContext(label_names=m.label_names, map=m)
    qs = h.expand("bunk bed", ctx)
    assert qs.positives == ["bunk bed", "bed"]
    assert qs.negatives == ["sofa", "futon", "piano", "grand piano", "lamp"]
    assert qs.provenance["labels_from"].endswith("scene.taxonomy.yaml")
    assert LabelListHeuristic().expand("futon", ctx).negatives == ["bed", "piano", "lamp"]
    # a file there that is not a taxonomy is ignored
    (tmp_path / "scene.taxonomy.yaml").write_text("- not a mapping\n")
    assert h.expand("bed", ctx).negatives == ["sofa", "lamp"]
    with pytest.raises(HeuristicError, match="no taxonomy"):
        h.expand("bed", ExpansionContext())


def test_quash_expand_shows_the_resolution(tmp_path, capsys):
    from quash_plugins.cli.main import main

    names = {n for k, v in TAX.items() for n in (k, *v)} | {"other", "background", "nothing"}
    np.savez(
        tmp_path / "text.npz",
        texts=np.asarray(sorted(names | {"Bunk-beds"})),
        embeddings=np.asarray([vec(n) for n in sorted(names | {"Bunk-beds"})], np.float32),
    )
    (tmp_path / "tax.yaml").write_text("bed: [bunk bed, cot]\nsofa: [futon]\n")
    (tmp_path / "c.yaml").write_text(
        "encoder: {name: table, file: text.npz}\n"
        "heuristic: {name: taxonomy, file: tax.yaml, n_antonyms: all}\ncache: false\n"
    )
    assert main(["expand", "Bunk-beds", "-c", str(tmp_path / "c.yaml")]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "query 'Bunk-beds' resolved to label 'bed' (near match of sub-class 'bunk bed')" in out
