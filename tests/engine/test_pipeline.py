from __future__ import annotations

import numpy as np
import pytest

from quash_plugins import LatentMap, Quash, QuerySet
from quash_plugins.core import registry
from quash_plugins.core.errors import DimensionMismatchError, MapFormatError, QuashError
from quash_plugins.core.text import ZERO_TOKEN
from quash_plugins.encoders import TableEncoder
from quash_plugins.engine.training import training_set


def _contrast_rule(E, T, words, query, negatives):
    """VLMaps' rule computed independently: cosine to query beats every negative."""
    En = E / np.linalg.norm(E, axis=1, keepdims=True)
    q = En @ T[words.index(query)]
    n = np.max(np.stack([En @ T[words.index(w)] for w in negatives]), axis=0)
    return q > n


def test_query_matches_independent_contrast_rule(tiny_world):
    quash = Quash.from_config(tiny_world["config"])
    results = quash.query_many(tiny_world["map"], ["chair", "sofa"])
    for r in results:
        expected = _contrast_rule(
            tiny_world["E"],
            tiny_world["T"],
            tiny_world["words"],
            r.query,
            ["other", "background", "nothing"],
        )
        np.testing.assert_array_equal(r.mask, expected)
        assert r.scores.dtype == np.float32 and r.scores.shape == (600,)
        assert set(r.timings) >= {"read", "expand", "encode", "fit", "classify", "total"}
        assert ((r.display_scores >= 0) & (r.display_scores <= 1)).all()
        # the mask really finds the label (contrast over-predicts, so recall, not precision)
        label = tiny_world["label_names"].index(r.query)
        assert r.mask[tiny_world["labels"] == label].mean() > 0.9


def test_map_is_read_once(tiny_world, monkeypatch):
    import quash_plugins.core.maps as adapters

    calls = []
    original = adapters.read_map
    monkeypatch.setattr(adapters, "read_map", lambda *a, **k: calls.append(a) or original(*a, **k))
    quash = Quash.from_config(tiny_world["config"])
    quash.query(tiny_world["map"], "chair")
    quash.query(tiny_world["map"], "sofa")
    assert len(calls) == 1


def test_a_rewritten_map_file_is_read_again(tiny_world):
    from quash_plugins.adapters import write_npz_map

    quash = Quash.from_config(tiny_world["config"])
    first = quash.read_map(tiny_world["map"])
    assert quash.read_map(tiny_world["map"]) is first  # unchanged: reused
    # a mapping process rewrites the file with more items
    E = np.concatenate([tiny_world["E"], tiny_world["E"][:50]])
    write_npz_map(LatentMap(E, positions=np.zeros((650, 3), np.float32)), tiny_world["map"])
    again = quash.read_map(tiny_world["map"])
    assert again is not first and again.n == 650
    assert quash.query(tiny_world["map"], "chair").mask.shape == (650,)


def test_a_map_folder_whose_files_are_rewritten_in_place_is_read_again(tiny_world, tmp_path):
    """gradslam's save_to_h5 rewrites pointclouds/pc_*.h5 in place, which leaves the
    folder's own time as it was: a Quash kept the old map, and its next query failed
    with 'pc_embeddings.h5 changed on disk since the map was read ... Query it again'."""
    from _cf_writers import cf_arrays, save_pointclouds

    quash = Quash.from_config(tiny_world["config"])
    folder = save_pointclouds(tmp_path / "saved-map", **cf_arrays(n=40, d=8, seed=0))
    first = quash.read_map(tmp_path / "saved-map")
    assert quash.read_map(tmp_path / "saved-map") is first  # unchanged: reused
    stamp = folder.stat().st_mtime_ns
    arrays = cf_arrays(n=40, d=8, seed=1)
    save_pointclouds(tmp_path / "saved-map", **arrays)  # the same files, rewritten
    assert folder.stat().st_mtime_ns == stamp
    again = quash.read_map(tmp_path / "saved-map")
    assert again is not first
    np.testing.assert_array_equal(np.asarray(again.embeddings), arrays["pc_embeddings"])


def test_a_live_map_whose_arrays_change_is_read_again(tiny_world):
    class VLMap:  # the attributes of VLMaps' class that the adapter reads
        def __init__(self, feat):
            self.grid_feat, self.grid_pos = feat, np.zeros((len(feat), 3), np.int64)

    quash = Quash.from_config(tiny_world["config"])
    E = tiny_world["E"]
    vlmap = VLMap(E[:300])
    opts = {"adapter": "vlmaps-live", "gs": 1000, "cs": 0.05}
    first = quash.read_map(vlmap, **opts)
    assert quash.read_map(vlmap, **opts) is first
    assert quash.read_map(vlmap, **{**opts, "cs": 0.1}) is not first  # other options
    # the robot explores: VLMaps replaces its arrays with larger ones
    vlmap.grid_feat, vlmap.grid_pos = E, np.zeros((600, 3), np.int64)
    grown = quash.read_map(vlmap, **opts)
    assert grown is not first and grown.n == 600
    expected = _contrast_rule(
        E, tiny_world["T"], tiny_world["words"], "sofa", ["other", "background", "nothing"]
    )
    result = quash.query(vlmap, "sofa", **opts)
    np.testing.assert_array_equal(result.mask, expected)
    # an object without weak references (a SimpleNamespace) is kept by a strong one
    from types import SimpleNamespace

    ns = SimpleNamespace(grid_feat=E[:300], grid_pos=np.zeros((300, 3), np.int64))
    first = quash.read_map(ns, **opts)
    assert quash.read_map(ns, **opts) is first
    ns.grid_feat, ns.grid_pos = E, np.zeros((600, 3), np.int64)
    assert quash.read_map(ns, **opts).n == 600


def test_at_most_keep_maps_maps_are_kept(tiny_world, tmp_path):
    from quash_plugins.adapters import write_npz_map

    paths = []
    for i in range(3):
        rows = tiny_world["E"][100 * i : 100 * i + 100]
        paths.append(write_npz_map(LatentMap(rows), tmp_path / f"m{i}.npz"))
    quash = Quash.from_config(tiny_world["config"])
    quash.keep_maps = 2
    maps = [quash.read_map(p) for p in paths]
    assert quash.read_map(paths[2]) is maps[2]
    assert quash.read_map(paths[0]) is not maps[0]  # the least recently used went first
    assert quash.read_map(paths[2]) is maps[2]  # kept: used more recently than paths[1]
    assert quash.read_map(paths[1]) is not maps[1]
    quash.forget_maps()
    assert quash.read_map(paths[2]) is not maps[2]


def test_chunking_does_not_change_results(tiny_world):
    big = Quash.from_config(tiny_world["config"])
    small = Quash.from_config(tiny_world["config"], chunk_mb=0.001)  # ~15 rows per chunk
    a = big.query(tiny_world["map"], "table")
    b = small.query(tiny_world["map"], "table")
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)


def test_zero_rows_never_match_and_normalize_flag():
    enc = TableEncoder(
        table={"chair": [1, 0], "other": [0, 1], "background": [-1, 0], "nothing": [0, -1]}
    )
    E = np.array([[3, 0.2], [0, 0], [0.1, 5]], dtype=np.float32)
    m = LatentMap(E, normalize=True)
    r = Quash(enc, classifier=registry.create("classifiers", "contrast")).query(m, "chair")
    assert r.mask.tolist() == [True, False, False]
    assert r.display_scores[1] == 0.0


def test_threshold_trades_precision_for_recall(tiny_world):
    base = Quash.from_config(tiny_world["config"]).query(tiny_world["map"], "chair")
    strict = Quash.from_config(tiny_world["config"], threshold=0.2).query(
        tiny_world["map"], "chair"
    )
    assert strict.n_matched < base.n_matched
    assert not (strict.mask & ~base.mask).any()


def test_generic_negatives_are_added_once():
    enc = TableEncoder(table={"chair": [1, 0], "other": [0, 1], "nothing": [0, -1]})
    quash = Quash(enc, negatives=["other", "nothing", "other"])
    qs = quash.expand("  chair ")
    assert (
        qs.query == "chair" and qs.positives == ["chair"] and qs.negatives == ["other", "nothing"]
    )


def test_dimension_mismatch_names_both_dims():
    enc = TableEncoder(table={"chair": [1, 0, 0], "other": [0, 1, 0]})
    m = LatentMap(np.ones((4, 512), dtype=np.float32), source={"path": "map.npz"})
    with pytest.raises(DimensionMismatchError) as err:
        Quash(enc).query(m, "chair")
    msg = str(err.value)
    assert "512" in msg and "3-dimensional" in msg and "lseg" in msg


def test_dimension_mismatch_names_the_config_and_the_dim_option(tmp_path):
    """Built from a config file: the message names the file's encoder section; an encoder
    that takes ``dim`` (a plugin's hashing encoder, say) is told which value to set."""
    from quash_plugins.core.interfaces import Encoder

    class Hashing(Encoder):
        name = "hashing"

        def __init__(self, dim: int = 8) -> None:
            self._dim = dim

        @property
        def dim(self) -> int:
            return self._dim

        def encode_text(self, texts):
            return np.ones((len(texts), self.dim), np.float32)

    cfg = tmp_path / "mine.yaml"
    cfg.write_text("encoder: {name: table, table: {chair: [1, 0, 0], other: [0, 1, 0]}}\n")
    m = LatentMap(np.ones((4, 96), dtype=np.float32), source={"path": "map.npz"})
    quash = Quash.from_config(cfg, cache=None)
    with pytest.raises(DimensionMismatchError) as err:
        quash.query(m, "chair")
    msg = str(err.value)
    assert f"the 'encoder:' section of {cfg}" in msg and "96-dimensional" in msg
    assert "dim: 96" not in msg  # the table encoder has no dim to set
    quash.encoder = Hashing()
    with pytest.raises(DimensionMismatchError) as err:
        quash.query(m, "chair")
    assert "Set 'encoder: {name: hashing, dim: 96}' if that model supports it" in str(err.value)


def test_nan_in_embeddings_is_reported_with_row():
    enc = TableEncoder(table={"chair": [1, 0], "other": [0, 1]})
    E = np.ones((10, 2), dtype=np.float32)
    E[7, 1] = np.nan
    with pytest.raises(MapFormatError, match="row 7"):
        Quash(enc, negatives=["other"]).query(LatentMap(E), "chair")


def test_empty_query_is_rejected():
    enc = TableEncoder(table={"chair": [1, 0], "other": [0, 1]})
    with pytest.raises(QuashError, match="query is empty"):
        Quash(enc).query(LatentMap(np.ones((2, 2), np.float32)), "   ")


def test_queryset_yaml_round_trip():
    qs = QuerySet(
        "chair",
        ["chair", "armchair", "chair"],
        ["other", "armchair"],
        {"heuristic": "static", "seed": np.int64(3)},
    )
    assert qs.positives == ["chair", "armchair"] and qs.negatives == ["other"]
    import yaml

    again = QuerySet.from_dict(yaml.safe_load(qs.to_yaml()))
    assert again.to_dict() == qs.to_dict()


def test_templates_mean_and_all_and_zero_vector():
    class Echo(TableEncoder):
        pass

    words = ["a chair", "the chair", "a other", "the other"]
    rng = np.random.default_rng(0)
    T = rng.normal(size=(4, 8))
    enc = Echo(table=dict(zip(words, T.tolist())))
    qs = QuerySet("chair", ["chair"], ["other", ZERO_TOKEN])
    X, y, texts = training_set(enc, qs, templates=["a {}", "the {}"], mode="mean")
    Tn = T / np.linalg.norm(T, axis=1, keepdims=True)
    expect = Tn[0] + Tn[1]
    np.testing.assert_allclose(X[0], expect / np.linalg.norm(expect), atol=1e-6)
    assert y.tolist() == [1, 0, 0] and not X[2].any()
    X, y, texts = training_set(enc, qs, templates=["a {}", "the {}"], mode="all")
    assert X.shape == (6, 8) and y.tolist() == [1, 1, 0, 0, 0, 0]
    assert texts[:4] == words and not X[4:].any()


def test_npz_round_trip_keeps_frames(tmp_path):
    from quash_plugins import FrameInfo
    from quash_plugins.adapters import read_map, write_npz_map

    frames = [FrameInfo("f0", 2, 3, 0), FrameInfo("f1", 1, 4, 6)]
    E = np.random.default_rng(0).normal(size=(10, 4)).astype(np.float32)
    path = write_npz_map(LatentMap(E, kind="pixels", frames=frames), tmp_path / "px.npz")
    back = read_map(path)
    assert back.kind == "pixels"
    assert [(f.frame_id, f.height, f.width, f.offset) for f in back.frames] == [
        ("f0", 2, 3, 0),
        ("f1", 1, 4, 6),
    ]


def test_atomic_write_gives_normal_permissions(tmp_path):
    import os
    import stat

    from quash_plugins.core.atomic import atomic_write_text

    mask = os.umask(0o022)
    try:
        path = atomic_write_text(tmp_path / "out.txt", "hello")
    finally:
        os.umask(mask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644
    assert path.read_text() == "hello"


def test_query_sets_are_not_reused_across_maps_with_recycled_ids():
    enc = TableEncoder(table={"chair": [1, 0], "other": [0, 1], "sofa": [1, 1]})

    class LabelEcho:
        name = "label-echo"

        def expand(self, query, context=None):
            return QuerySet(query, [query], list(context.label_names or ["other"]))

    quash = Quash(enc, LabelEcho(), negatives=[])
    first = LatentMap(np.ones((2, 2), np.float32), labels=np.array([0, 0]), label_names=["other"])
    assert quash.expand("chair", first).negatives == ["other"]
    key = next(iter(quash._querysets))
    del first
    second = LatentMap(np.ones((2, 2), np.float32), labels=np.array([0, 0]), label_names=["sofa"])
    # simulate the allocator handing the freed id to the new map
    quash._querysets[("chair", id(second))] = quash._querysets.pop(key)
    assert quash.expand("chair", second).negatives == ["sofa"]


def _finish_reference(post, display, raw, observed, threshold):
    """What ``engine.answer.finish`` must return, spelled out on float64 copies."""
    raw = raw.astype(np.float64)
    out = raw.copy()
    if observed.any():
        out[observed] = post(raw[observed])
        floor = min(out[observed].min(), threshold) - 1.0
    else:
        floor = threshold - 1.0
    out[~observed] = floor
    mask = (out > threshold) & observed
    disp = display(out, threshold)
    disp[~observed] = 0.0
    return out, mask, disp


def _logistic(scores, threshold):
    s = scores - threshold
    scale = s.std() if s.std() > 1e-6 else 1.0
    return 0.5 * (1.0 + np.tanh(s / (2.0 * scale)))


@pytest.mark.parametrize("every", [True, False])
@pytest.mark.parametrize("post", ["identity", "minmax"])
def test_finish_matches_its_definition_with_and_without_unobserved_items(every, post):
    from quash_plugins.core.interfaces import Classifier

    class Clf(Classifier):
        def fit(self, X, y):
            return self

        def decision_function(self, X):
            return X[:, 0]

    class MinMax(Clf):
        def postprocess_scores(self, scores):
            s = np.asarray(scores, np.float32)
            return (s - s.min()) / max(float(s.max() - s.min()), 1e-12) - 0.5

    rng = np.random.default_rng(3)
    raw = rng.normal(0.2, 1.5, size=5001).astype(np.float32)
    observed = np.ones(raw.size, bool) if every else rng.random(raw.size) > 0.1
    clf = MinMax() if post == "minmax" else Clf()
    ref_post = (
        (lambda s: (s - s.min()) / (s.max() - s.min()) - 0.5) if post == "minmax" else (lambda s: s)
    )
    from quash_plugins.engine.answer import finish

    threshold = 0.1
    given = raw.copy()
    got_raw, got_mask, got_disp = finish(clf, given, observed, threshold)
    want_raw, want_mask, want_disp = _finish_reference(
        ref_post, _logistic, raw, observed, threshold
    )
    assert got_raw.dtype == np.float32 and got_disp.dtype == np.float32
    np.testing.assert_allclose(got_raw, want_raw, atol=1e-5)
    np.testing.assert_array_equal(got_mask, want_mask)
    np.testing.assert_allclose(got_disp, want_disp, atol=1e-5)
    # 0.5 sits at the threshold and unobserved items show 0
    at = np.abs(want_raw - threshold) < 1e-3
    assert np.allclose(got_disp[at & observed], 0.5, atol=1e-2)
    assert (got_disp[~observed] == 0).all()


def test_default_display_scores_leave_their_input_alone():
    from quash_plugins.core.interfaces import Classifier

    s = np.linspace(-2, 3, 101).astype(np.float32)
    before = s.copy()
    d = Classifier.display_scores(None, s, 0.5)
    np.testing.assert_array_equal(s, before)
    np.testing.assert_allclose(d, _logistic(before.astype(np.float64), 0.5), atol=1e-6)
    assert d.dtype == np.float32 and d[np.argmin(np.abs(s - 0.5))] == pytest.approx(0.5, abs=0.01)


def test_plugin_names_are_built_like_a_config_and_bad_arguments_refused_when_built():
    """``Quash(enc, heuristic="none", classifier="contrast")`` builds the named plugins
    through the registry (a name used to fail at the first query: "'str' object has no
    attribute 'expand'"); ``{"name": ..., **params}`` too. A wrong name or a non-plugin
    is refused by the constructor, naming the argument."""
    from quash_plugins.core.errors import ConfigError, PluginError

    table = {"chair": [1, 0, 0], "other": [0, 1, 0], "background": [0, 0, 1], "nothing": [0, 1, 1]}
    enc = TableEncoder(table=table)
    m = LatentMap(np.array([[1, 0.1, 0], [0, 1, 0.2]], dtype=np.float32))
    by_name = Quash(enc, heuristic="none", classifier="contrast", instances=None)
    by_object = Quash(
        enc,
        registry.create("heuristics", "none"),
        registry.create("classifiers", "contrast"),
        instances=None,
    )
    a, b = by_name.query(m, "chair"), by_object.query(m, "chair")
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_array_equal(a.scores, b.scores)
    assert type(by_name.heuristic) is type(by_object.heuristic)
    svm = Quash(enc, classifier={"name": "svm-rbf", "C": 2.0}).classifier
    assert svm.get_params()["C"] == 2.0
    with pytest.raises(PluginError, match="Quash: heuristic: .*'nonee'.*Did you mean 'none'"):
        Quash(enc, heuristic="nonee")
    with pytest.raises(ConfigError, match="Quash: classifier: .*'Cx'"):
        Quash(enc, classifier={"name": "svm-rbf", "Cx": 2.0})
    with pytest.raises(ConfigError, match="Quash: heuristic must be an object with expand"):
        Quash(enc, heuristic=3)
    with pytest.raises(ConfigError, match="Quash: encoder must be .* such as 'minilm'"):
        Quash(None)


def test_a_pipeline_prints_as_one_line_naming_its_plugins_and_stages():
    """print(quash) in a notebook: which config and plugins answer, not an address."""
    enc = TableEncoder(table={"chair": [1.0, 0.0], "other": [0.0, 1.0]})
    plain = Quash(enc, name="mine", device="cpu")
    assert repr(plain) == (
        "Quash(name='mine', encoder='table', heuristic='none', classifier='nearest-sample', "
        "refine=None, presence='off', backend='numpy', device='cpu')"
    )
    full = Quash(
        enc,
        heuristic="taxonomy",
        classifier={"name": "contrast"},
        refine={"classifier": {"name": "svm-rbf"}},
        presence={},
        name="full",
    )
    text = repr(full)
    assert "\n" not in text and " at 0x" not in text
    for part in ("name='full'", "heuristic='taxonomy'", "classifier='contrast'",
                 "refine='svm-rbf'", "presence='on'"):  # fmt: skip
        assert part in text, (part, text)


def test_from_config_overrides_a_plugin_section_as_the_config_would_set_it(tiny_world):
    """``Quash.from_config(cfg, heuristic=...)`` (a shipped config pointed at one's own
    label list) raised "Quash.__init__() got multiple values for argument 'heuristic'",
    and ``adapter={"name": "vlmaps", "cs": 0.05}`` was "Adapter \"{'name': ...}\" is not
    registered". Each override now answers as the same section written in the file."""
    from quash_plugins.core.errors import ConfigError

    d = tiny_world["dir"]
    table = TableEncoder(file=str(tiny_world["table"]))
    written = d / "written.yaml"
    written.write_text(
        tiny_world["config"]
        .read_text()
        .replace("classifier: contrast", "classifier: {name: svm-rbf, C: 2.0}")
        + "adapter: {name: npz}\n"
    )
    expected = Quash.from_config(written, cache=None).query(tiny_world["map"], "chair")
    overridden = Quash.from_config(
        tiny_world["config"],
        cache=None,
        encoder=table,
        classifier={"name": "svm-rbf", "C": 2.0},
        adapter={"name": "npz"},
    )
    assert overridden.encoder is table
    assert overridden.classifier.get_params()["C"] == 2.0
    got = overridden.query(tiny_world["map"], "chair")
    np.testing.assert_array_equal(got.mask, expected.mask)
    np.testing.assert_allclose(got.scores, expected.scores, rtol=1e-6)
    # an adapter mapping's options are the adapter's, as in a config's adapter: section
    bad = Quash.from_config(tiny_world["config"], adapter={"name": "npz", "bogus": 1})
    with pytest.raises(ConfigError, match="'npz' does not accept parameter 'bogus'"):
        bad.read_map(tiny_world["map"])
    # the config's own section is not built when overridden: an encoder file that is gone
    broken = d / "broken.yaml"
    broken.write_text(tiny_world["config"].read_text().replace("text.npz", "gone.npz"))
    with pytest.raises(QuashError, match="gone.npz"):
        Quash.from_config(broken)
    fixed = Quash.from_config(broken, encoder=table, heuristic="taxonomy")
    assert fixed.encoder is table and type(fixed.heuristic).__name__ == "TaxonomyHeuristic"


def test_from_config_refuses_a_misspelt_override_naming_the_ones_it_takes(tiny_world):
    """``Quash.from_config(cfg, treshold=0.2)`` built the config's plugins, then raised
    TypeError "Quash.__init__() got an unexpected keyword argument 'treshold'", naming
    neither what it takes nor the near name; ``evaluate(overrides=...)`` the same."""
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.evaluation import evaluate

    with pytest.raises(ConfigError, match=r"from_config: unknown option 'treshold'") as e:
        Quash.from_config(tiny_world["config"], treshold=0.2)
    assert "Did you mean 'threshold'?" in str(e.value) and "instances" in str(e.value)
    with pytest.raises(ConfigError, match=r"unknown option 'instance'.*'instances'\?"):
        evaluate(tiny_world["map"], [tiny_world["config"]], overrides={"instance": False})
    assert Quash.from_config(tiny_world["config"], threshold=0.2, cache=None).threshold == 0.2


def test_a_bare_array_given_as_the_map_is_told_to_be_wrapped_in_a_latent_map(tiny_world):
    """``quash.query(embeddings, "chair")`` read "No adapter recognises ndarray. ...
    Pass adapter=NAME to choose one.", though no adapter reads an array."""
    quash = Quash.from_config(tiny_world["config"], cache=None)
    emb = np.asarray(quash.read_map(tiny_world["map"]).embeddings)
    with pytest.raises(MapFormatError) as e:
        quash.query(emb, "chair")
    msg = str(e.value)
    assert f"ndarray of shape {emb.shape} is not a map" in msg
    assert "LatentMap(embeddings, kind='points'" in msg and "adapter=NAME" not in msg
    # what it says to do answers as the map itself does
    wrapped = quash.query(LatentMap(emb, kind="points"), "chair")
    np.testing.assert_array_equal(wrapped.scores, quash.query(tiny_world["map"], "chair").scores)


def test_an_override_that_fails_is_named_as_the_argument_not_the_config_file(tiny_world):
    """An override of Quash.from_config that failed was blamed on the config file
    (``c.yaml: adapter: ... does not accept parameter 'bogus'``; a wrong-size encoder
    "(the 'encoder:' section of c.yaml)"), which the user had not changed."""
    from quash_plugins.core.errors import ConfigError
    from quash_plugins.testing import HashingEncoder

    cfg = tiny_world["config"]
    bad = Quash.from_config(cfg, cache=None, adapter={"name": "npz", "bogus": 1})
    with pytest.raises(ConfigError) as err:
        bad.read_map(tiny_world["map"])
    said = str(err.value)
    assert said.startswith("Quash.from_config(adapter=...): ") and str(cfg) not in said
    lmap = Quash.from_config(cfg, cache=None).read_map(tiny_world["map"])
    wrong = HashingEncoder(lmap.dim + 3)
    with pytest.raises(DimensionMismatchError) as err:
        Quash.from_config(cfg, cache=None, encoder=wrong).query(lmap, "chair")
    assert "'encoder:' section" not in str(err.value) and str(cfg) not in str(err.value)
    # the file's own sections are still named as the file's
    own = tiny_world["dir"] / "own.yaml"
    own.write_text(cfg.read_text() + "adapter: {name: npz, bogus: 1}\n")
    with pytest.raises(ConfigError, match=f"^{own}: adapter: "):
        Quash.from_config(own, cache=None).read_map(tiny_world["map"])


def test_an_adapter_option_given_as_an_override_is_said_to_come_from_it(tmp_path):
    from _vlmaps_writers import mobile_map, write_vlmaps_h5df

    cam = {"pcd_min": [-2.5, -0.3, 1.25], "pcd_max": [4.0, 2.0, 6.0], "cs": 0.04}
    path = write_vlmaps_h5df(tmp_path / "vlmap_cam" / "vlmaps_cam.h5df", mobile_map(), camera=cam)
    config = tmp_path / "quash.yaml"
    config.write_text(
        "encoder: {name: table, table: {chair: [1, 0, 0, 0, 0, 0, 0, 0]}}\n"
        "heuristic: none\ncache: false\n"
    )
    q = Quash.from_config(str(config), adapter={"name": "vlmaps", "cs": 0.05})
    with pytest.raises(MapFormatError) as info:
        q.read_map(path)
    text = str(info.value)
    assert "cs=0.05 comes from the adapter= argument of Quash.from_config" in text
    assert str(config) not in text
