"""The ``vlmaps`` baseline is VLMaps' own ``index_map`` rule, exactly.

VLMaps averages each label's text embeddings (each L2-normalised) over its prompt
templates, does not re-normalise the mean, scores the raw map features against
``[categories..., "other"]`` and takes the argmax (ties to the earlier column). The
templates come from the user's installed VLMaps, located without importing it; here a
fake installed ``vlmaps`` package with templates of the tests' own invention stands in
(VLMaps' own template text is never copied into this repository).
"""

from __future__ import annotations

import sys

import numpy as np
import pytest
import yaml
from _vlmaps_writers import build_mobile_map, save_3d_map

from quash_plugins import Quash, QuashConfig
from quash_plugins.core.errors import ConfigError
from quash_plugins.core.text import (
    VLMAPS_OR_DEFAULT,
    load_templates,
    resolve_templates,
    vlmaps_templates_file,
)
from quash_plugins.integrations.vlmaps import index_map

#: The tests' own templates (not VLMaps').
TEST_TEMPLATES = ["{} seen by the test.", "the test's own {}.", "a sketch of {} for testing.",
                  "{} in a unit test."]  # fmt: skip
D = 16
LABELS = ["chair", "sofa", "table", "other"]


@pytest.fixture
def fake_vlmaps(tmp_path, monkeypatch):
    """An installed-looking ``vlmaps`` package whose import would fail loudly."""
    site = tmp_path / "site"
    pkg = site / "vlmaps"
    (pkg / "utils").mkdir(parents=True)  # like VLMaps: utils/ has no __init__.py
    (pkg / "__init__.py").write_text("raise RuntimeError('vlmaps must not be imported')\n")
    (pkg / "utils" / "clip_utils.py").write_text(
        "import torch  # never executed by quash\nimport clip\n\n"
        "multiple_templates = ['an old draft {}.']\n"
        f"multiple_templates = {TEST_TEMPLATES!r}\n\n"
        "def get_text_feats(*args):\n    raise RuntimeError\n"
    )
    monkeypatch.syspath_prepend(str(site))
    monkeypatch.delitem(sys.modules, "vlmaps", raising=False)
    return pkg


def shipped_default_templates() -> list[str]:
    """Our default list, read from the package's file here (not through load_templates)."""
    from importlib import resources

    text = resources.files("quash_plugins.data").joinpath("prompt_templates.txt").read_text()
    return [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]


def test_templates_read_from_installed_vlmaps_without_importing_it(fake_vlmaps):
    assert vlmaps_templates_file() == fake_vlmaps / "utils" / "clip_utils.py"
    assert load_templates("vlmaps") == TEST_TEMPLATES  # the last assignment, as in Python
    assert "vlmaps" not in sys.modules and "clip" not in sys.modules
    # a clone that is not installed: point at the file (or a text file) directly
    assert load_templates(str(fake_vlmaps / "utils" / "clip_utils.py")) == TEST_TEMPLATES


def test_templates_without_vlmaps_fall_back_with_a_warning(no_vlmaps, caplog, tmp_path):
    with caplog.at_level("INFO"):
        assert load_templates("vlmaps") == shipped_default_templates()
        load_templates("vlmaps")  # a second config: said again at INFO, not warned
    said = [r for r in caplog.records if "not VLMaps' exactly" in r.getMessage()]
    assert [r.levelname for r in said] == ["WARNING", "INFO"]
    assert "vlmaps-or-default" in said[0].getMessage()  # the quiet spelling is offered
    bad = tmp_path / "clip_utils.py"
    bad.write_text("templates = ['a {}']\n")
    with pytest.raises(ConfigError, match=r"clip_utils\.py.*multiple_templates"):
        load_templates(str(bad))


def test_vlmaps_or_default_takes_installed_vlmaps_templates_silently(fake_vlmaps, caplog):
    with caplog.at_level("DEBUG", logger="quash_plugins"):
        resolved = resolve_templates(VLMAPS_OR_DEFAULT)
    assert resolved.templates == TEST_TEMPLATES
    assert str(fake_vlmaps / "utils" / "clip_utils.py") in resolved.source
    assert not [r for r in caplog.records if "VLMaps" in r.getMessage()]
    assert "vlmaps" not in sys.modules


def test_vlmaps_or_default_without_vlmaps_is_our_list_said_at_info(no_vlmaps, caplog):
    with caplog.at_level("DEBUG", logger="quash_plugins"):
        first = resolve_templates(VLMAPS_OR_DEFAULT)
        again = resolve_templates(VLMAPS_OR_DEFAULT)  # a second config: DEBUG only
    assert first.templates == again.templates == shipped_default_templates()
    assert "default" in first.source and "no VLMaps" in first.source
    said = [r for r in caplog.records if "no installed VLMaps" in r.getMessage()]
    assert [r.levelname for r in said] == ["INFO", "DEBUG"]
    assert all("vlmaps-or-default" in r.getMessage() for r in said)
    # and `vlmaps` keeps its own warning after the quiet spec was said
    caplog.clear()
    with caplog.at_level("INFO"):
        load_templates("vlmaps")
    assert [r.levelname for r in caplog.records if "not VLMaps' exactly" in r.getMessage()] == [
        "WARNING"
    ]


@pytest.mark.parametrize(
    ("spec", "near"), [("vlmaps-or-defualt", "vlmaps-or-default"), ("vlmap", "vlmaps")]
)
def test_a_misspelt_template_name_is_named_with_the_known_ones(spec, near, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=rf"{spec!r} is not a template list.*{near!r}"):
        load_templates(spec)
    config = tmp_path / "mine.yaml"  # in a config: its file and line
    config.write_text(
        f"name: mine\nencoder: minilm\nprompt_templates: {{mode: mean, templates: {spec}}}\n"
    )
    with pytest.raises(ConfigError, match=rf"mine\.yaml:3: .*{spec!r}.*default, vlmaps, "):
        QuashConfig.from_yaml(config)
    with pytest.raises(ConfigError, match=r"not found: .*nope\.txt.*vlmaps-or-default"):
        load_templates(str(tmp_path / "nope.txt"))  # a file's name: the file is missing


# ----------------------------------------------------------------------------- the rule
def reference_index_map(grid_feat, embed, query, categories=None):
    """An independent re-implementation of VLMaps' ``VLMap.index_map``.

    ``embed(text)`` is the text tower (unit vectors). With ``categories``
    (``with_init_cat=True``) the label list is the categories, else ``[query]``; "other"
    is appended unless the list already ends with it.
    """
    labels = list(categories) if categories is not None else [query]
    if labels[-1] != "other":
        labels.append("other")
    text = np.stack(
        [np.mean([embed(t.format(lab)) for t in TEST_TEMPLATES], axis=0) for lab in labels]
    ).astype(np.float32)  # the mean, not re-normalised
    scores = np.asarray(grid_feat, dtype=np.float32) @ text.T
    cat_id = labels.index(query) if categories is not None else 0
    return np.argmax(scores, axis=1) == cat_id


def renormalised_rule(grid_feat, embed, query):
    """What the package did before: re-normalised means, a tie is no match."""
    text = []
    for lab in (query, "other"):
        m = np.mean([embed(t.format(lab)) for t in TEST_TEMPLATES], axis=0)
        text.append(m / np.linalg.norm(m))
    s = np.asarray(grid_feat, np.float64) @ np.asarray(text, np.float64).T
    return s[:, 0] > s[:, 1]


def write_config(tmp_path, table):
    (tmp_path / "table.yaml").write_text(yaml.safe_dump({k: list(map(float, v))
                                                         for k, v in table.items()}))  # fmt: skip
    cfg = {
        "name": "vlmaps",
        "encoder": {"name": "table", "file": "table.yaml"},
        "heuristic": "none",
        "negatives": ["other"],
        "classifier": {"name": "label-argmax", "normalize_text": False, "ties": "earlier"},
        "prompt_templates": {"mode": "mean", "templates": "vlmaps", "normalize": False},
        "instances": False,
        "cache": False,
    }
    path = tmp_path / "vlmaps.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def random_table(seed=0):
    """Each label's templated strings scatter around a label direction; "other" scatters
    most, so the means' norms differ per label (where re-normalising changes argmaxes)."""
    rng = np.random.default_rng(seed)
    spread = {"chair": 0.4, "sofa": 0.6, "table": 0.8, "other": 2.0}
    table = {}
    for lab in LABELS:
        base = rng.normal(size=D)
        for t in TEST_TEMPLATES:
            table[t.format(lab)] = (
                base / np.linalg.norm(base) + spread[lab] * rng.normal(size=D) / 4
            )
    return table


def unit(v):
    v = np.asarray(v, dtype=np.float32)
    return v / np.linalg.norm(v)


def saved_map(tmp_path, feats):
    """A VLMaps mobile-base map holding ``feats`` (one point per cell), as upstream saves it."""
    n = len(feats)
    side = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    pts = np.column_stack([(i // side) * 0.1 + 0.025, (i % side) * 0.1 + 0.025, np.full(n, 0.3)])
    arrays, row_of = build_mobile_map(pts, feats, np.zeros((n, 3), np.uint8), gs=400, cs=0.05)
    assert (row_of == np.arange(n)).all()
    return save_3d_map(tmp_path / "vlmap" / "vlmaps.h5df", **arrays), arrays["grid_feat"]


def test_baseline_matches_index_map_on_random_rows(tmp_path, fake_vlmaps):
    table = random_table()
    embed = lambda s: unit(table[s])  # noqa: E731 - the text tower of the reference
    rng = np.random.default_rng(1)
    means = {lab: np.mean([embed(t.format(lab)) for t in TEST_TEMPLATES], 0) for lab in LABELS}
    # rows mixing the labels' directions, arbitrary norms (VLMaps' features are not unit)
    w = rng.dirichlet(np.ones(len(LABELS)) * 0.7, size=3000)
    feats = (w @ np.stack([means[lab] for lab in LABELS])) + rng.normal(0, 0.05, (3000, D))
    feats = (feats * rng.uniform(0.2, 9.0, (3000, 1))).astype(np.float32)
    path, grid_feat = saved_map(tmp_path, feats)
    quash = Quash.from_config(write_config(tmp_path, table))
    for query in ("chair", "sofa", "table"):
        expected = reference_index_map(grid_feat, embed, query)
        got = quash.query(path, query).mask
        np.testing.assert_array_equal(got, expected)
        assert 0 < expected.sum() < len(expected)
    # the test can tell VLMaps' rule from the re-normalised one
    differs = sum(
        int((renormalised_rule(grid_feat, embed, q) != reference_index_map(grid_feat, embed, q)).sum())
        for q in ("chair", "sofa", "table")
    )  # fmt: skip
    assert differs > 20
    # with categories, through the drop-in (a live VLMap-like object)
    from types import SimpleNamespace

    live = SimpleNamespace(grid_feat=grid_feat, grid_pos=np.zeros((len(grid_feat), 3), int) + 200,
                           gs=400, categories=["sofa", "chair", "table"])  # fmt: skip
    cfg = tmp_path / "vlmaps.yaml"
    for query in ("sofa", "chair", "table"):
        expected = reference_index_map(grid_feat, embed, query, live.categories)
        np.testing.assert_array_equal(index_map(live, query, quash=cfg), expected)
        no_cat = index_map(live, query, with_init_cat=False, quash=cfg)
        np.testing.assert_array_equal(no_cat, reference_index_map(grid_feat, embed, query))


def dyadic_table():
    """Text vectors whose every operation is exact (four entries of 0.5: unit norms;
    means of multiples of 0.5), so that crafted map rows tie exactly, in VLMaps'
    arithmetic and in ours. Mean over the templates: chair (0.5, 0.25, 0.5, 0.25) on
    coords 0-3, sofa (0.25, 0.5, 0, 0), table (0, 0, 0.25, 0.5); other lives on 4-7."""

    def vec(coords):
        v = np.zeros(D)
        v[list(coords)] = 0.5
        assert len(coords) == 4
        return v

    table = {}
    for i, t in enumerate(TEST_TEMPLATES):
        even = i % 2 == 0
        table[t.format("chair")] = vec([0, 1, 2, 8 + i] if even else [0, 2, 3, 8 + i])
        table[t.format("sofa")] = vec([0, 1, 12, 13] if even else [1, 12, 13, 14])
        table[t.format("table")] = vec([3, 13, 14, 15] if even else [2, 3, 14, 15])
        table[t.format("other")] = vec([4, 5, 6, 7] if even else [4, 5, 6, 11])
    return table


def test_ties_go_to_the_earlier_column(tmp_path, fake_vlmaps):
    table = dyadic_table()
    embed = lambda s: unit(table[s])  # noqa: E731
    m = {lab: np.mean([embed(t.format(lab)) for t in TEST_TEMPLATES], 0) for lab in LABELS}
    feats = np.zeros((6, D), np.float32)
    feats[0, [0, 1]] = 3.0  # chair == sofa, above table and other
    feats[1, [2, 3]] = 2.0  # chair == table, above sofa and other
    feats[2, 0] = 1.0  # chair alone
    feats[3, [4, 5]] = 1.0  # other
    feats[4, :4] = 1.0  # chair alone
    feats[5, [0, 1]] = 0.25  # chair == sofa again, at another scale
    s = feats @ np.stack([m[lab] for lab in LABELS]).T
    assert s[0, 0] == s[0, 1] > max(s[0, 2:]) and s[5, 0] == s[5, 1] > max(s[5, 2:])
    assert s[1, 0] == s[1, 2] > max(s[1, 1], s[1, 3])  # exact ties, as constructed
    path, grid_feat = saved_map(tmp_path, feats)
    quash = Quash.from_config(write_config(tmp_path, table))
    for query in ("chair", "sofa", "table"):
        expected = reference_index_map(grid_feat, embed, query)
        np.testing.assert_array_equal(quash.query(path, query).mask, expected)
    assert reference_index_map(grid_feat, embed, "sofa")[0]  # [sofa, other]: sofa wins the tie
    from types import SimpleNamespace

    cfg = tmp_path / "vlmaps.yaml"
    for cats in (
        ["sofa", "chair", "table"],
        ["chair", "sofa", "table"],
        ["table", "chair", "sofa"],
    ):
        live = SimpleNamespace(grid_feat=grid_feat, grid_pos=np.full((6, 3), 200), gs=400,
                               categories=cats)  # fmt: skip
        for query in cats:
            expected = reference_index_map(grid_feat, embed, query, cats)
            np.testing.assert_array_equal(
                index_map(live, query, quash=cfg), expected, err_msg=f"{cats} {query}"
            )
    # the earlier category wins: chair after sofa loses row 0, chair before sofa keeps it
    assert not reference_index_map(grid_feat, embed, "chair", ["sofa", "chair", "table"])[0]
    assert reference_index_map(grid_feat, embed, "chair", ["chair", "sofa", "table"])[0]


def test_label_argmax_parameters():
    from quash_plugins.core import registry
    from quash_plugins.core.errors import ConfigError as CE

    clf = registry.create("classifiers", "label-argmax", normalize_text=False, ties="earlier")
    assert clf.get_params()["query_column"] == 0
    for bad in ({"ties": "later"}, {"query_column": -1}, {"query_column": 1.5}):
        with pytest.raises(CE, match="label-argmax"):
            registry.create("classifiers", "label-argmax", **bad)
    X = np.array([[2.0, 0.0], [0.0, 0.5]], np.float32)  # norms kept: 2 and 0.5
    fitted = registry.create("classifiers", "label-argmax", normalize_text=False).fit(X, [1, 0])
    np.testing.assert_allclose(np.linalg.norm(fitted.positives_, axis=1), [2.0])
    E = np.array([[1.0, 3.0]], np.float32)  # 2 * 1 > 0.5 * 3: the query wins unnormalised
    assert fitted.decision_function(E)[0] > 0
    unit_rule = registry.create("classifiers", "label-argmax").fit(X, [1, 0])
    assert unit_rule.decision_function(E)[0] < 0


def test_eval_without_configs_warns_about_vlmaps_templates_only_when_asked(no_vlmaps, caplog):
    """``quash eval MAP`` (no -c) runs the VLMaps peer the user did not choose: its
    ``templates: vlmaps-or-default`` takes the default templates without an installed
    VLMaps, said at INFO, not a warning; a config that names ``templates: vlmaps`` itself
    is still warned about."""
    import dataclasses
    import logging

    from quash_plugins.cli._config_opts import fair_default_configs

    with caplog.at_level(logging.INFO):
        configs = fair_default_configs()
        quashes = [Quash.from_config(c) for c in configs]
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]
    peer = next(c for c in configs if c.name == "vlmaps-labels")
    assert peer.prompt_templates == {
        "mode": "mean",
        "templates": VLMAPS_OR_DEFAULT,
        "normalize": False,
    }
    built = quashes[configs.index(peer)]
    assert built._templates == shipped_default_templates()
    assert "no VLMaps installed" in built.templates_source
    assert [r.levelname for r in caplog.records if "no installed VLMaps" in r.getMessage()] == [
        "INFO"
    ]
    caplog.clear()
    asked = dataclasses.replace(
        peer, prompt_templates={**peer.prompt_templates, "templates": "vlmaps"}
    )
    with caplog.at_level(logging.INFO):
        Quash.from_config(asked)  # asked for: warned
    said = [r for r in caplog.records if "not VLMaps' exactly" in r.getMessage()]
    assert [r.levelname for r in said] == ["WARNING"]


def test_eval_without_configs_uses_installed_vlmaps_templates(fake_vlmaps):
    from quash_plugins.cli._config_opts import fair_default_configs

    configs = fair_default_configs()
    peer = next(c for c in configs if c.name == "vlmaps-labels")
    built = Quash.from_config(peer)
    assert built._templates == TEST_TEMPLATES
    assert built.templates_source == f"VLMaps' list ({fake_vlmaps / 'utils' / 'clip_utils.py'})"


@pytest.mark.parametrize("name", ["demo:vlmaps", "demo:vlmaps-labels", "lseg:vlmaps"])
def test_shipped_vlmaps_configs_take_our_list_without_vlmaps(name, no_vlmaps, caplog):
    """Scores stay as measured: without VLMaps every shipped VLMaps config resolves to our
    default list; the demo peers say so at INFO, lseg:vlmaps (a real map, where VLMaps'
    own list is expected) warns."""
    import logging

    spec = QuashConfig.from_yaml(name).prompt_templates["templates"]
    with caplog.at_level(logging.INFO):
        assert load_templates(spec) == shipped_default_templates()
    levels = {r.levelname for r in caplog.records if "VLMaps" in r.getMessage()}
    assert levels == ({"WARNING"} if name.startswith("lseg:") else {"INFO"})
