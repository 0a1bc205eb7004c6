"""docs/vlmaps.md: every code block runs against a fake VLMap and a small .h5df."""

from __future__ import annotations

import re
import shlex
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pytest
import yaml
from _vlmaps_writers import mobile_map, sha256, write_vlmaps_h5df

from quash_plugins.core.config import QuashConfig
from quash_plugins.integrations.vlmaps import (
    QuashIndexMixin,
    index_map,
    patch_vlmap,
    unpatch_vlmap,
)

DOC = Path(__file__).resolve().parents[2] / "docs" / "vlmaps.md"
D = 8
WORDS = ["chair", "sofa", "other", "background", "nothing"]


def blocks(lang):
    return re.findall(rf"```{lang}\n(.*?)```", DOC.read_text(encoding="utf-8"), flags=re.S)


def features(n, seed):
    """Rows near chair (e0), sofa (e1) or other (e2), each leaning towards "other" so that
    a chair row loses to "other" on the sofa query and vice versa; two zero rows."""
    rng = np.random.default_rng(seed)
    kind = rng.integers(0, 3, n)
    feat = np.eye(D)[kind] + rng.normal(0, 0.05, (n, D))
    feat[:, 2] += 0.5
    feat *= rng.uniform(0.2, 8, (n, 1))
    feat[:2] = 0
    kind[:2] = -1
    return feat.astype(np.float32), kind


class FakeVLMap:
    """What VLMaps' ``VLMap`` exposes after ``load_map`` (mobile base)."""

    def __init__(self, n=80, seed=0):
        arrays = mobile_map(n=n, d=D, seed=seed)
        self.grid_feat, self.kind = features(n, seed)
        self.grid_pos = arrays["grid_pos"]
        self.grid_rgb = arrays["grid_rgb"]
        self.gs, self.cs = 1000, 0.05
        self.map_config = {"pose_info": {"pose_type": "mobile_base"}}
        self.categories = None

    def index_map(self, language_desc, with_init_cat=True):
        raise AssertionError("VLMaps' own index_map must not run once patched")

    def get_pos(self, name):  # like VLMaps: builds on index_map
        return self.grid_pos[self.index_map(name, with_init_cat=True)]


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A VLMaps project folder with a table-encoder quash.yaml and a saved map."""
    table = {w: np.eye(D)[i].tolist() for i, w in enumerate(WORDS)}
    (tmp_path / "table.yaml").write_text(yaml.safe_dump(table))
    cfg = {
        "encoder": {"name": "table", "file": "table.yaml"},
        "classifier": "contrast",
        "cache": False,
    }
    (tmp_path / "quash.yaml").write_text(yaml.safe_dump(cfg))
    arrays = mobile_map(n=60, d=D, seed=5)
    arrays["grid_feat"], kind = features(60, 5)
    h5 = write_vlmaps_h5df(tmp_path / "data/scene/vlmap/vlmaps.h5df", arrays)
    # a 2023 top-down grid of the same rows, at random cells of a 20 x 20 grid
    cells = np.random.default_rng(6).choice(400, size=60, replace=False)
    grid = np.zeros((400, D), np.float32)
    grid[cells] = arrays["grid_feat"]
    (tmp_path / "data/scene/map").mkdir()
    np.save(tmp_path / "data/scene/map/grid_lseg_1.npy", grid.reshape(20, 20, D))
    monkeypatch.chdir(tmp_path)
    return {"h5": h5, "kind": kind, "cells": cells, "grid_pos": arrays["grid_pos"]}


def test_doc_has_the_examples():
    assert len(blocks("python")) >= 3 and blocks("yaml") and blocks("bash")


def test_yaml_block_is_a_valid_config(tmp_path):
    path = tmp_path / "quash.yaml"
    path.write_text(blocks("yaml")[0])
    cfg = QuashConfig.load(path)
    assert cfg.encoder.name == "open-clip" and cfg.adapter.name == "vlmaps"
    assert cfg.adapter.params == {"cs": 0.05}


def test_a_yaml_block_that_names_a_shipped_config_is_that_config():
    """The baseline block was said to be demo-vlmaps.yaml, whose encoder is MiniLM."""
    configs = Path(__file__).resolve().parents[2] / "quash_plugins" / "data" / "configs"
    text = DOC.read_text(encoding="utf-8")
    checked = 0
    for m in re.finditer(r"```yaml\n(.*?)```", text, flags=re.S):
        paragraph = text[: m.start()].rsplit("\n\n", 2)[-2]
        for name in re.findall(r"quash_plugins/data/configs/([\w-]+\.yaml)", paragraph):
            shipped = yaml.safe_load((configs / name).read_text(encoding="utf-8"))
            assert yaml.safe_load(m.group(1)) == shipped, name
            checked += 1
    assert checked


def test_python_blocks_run(project, capsys):
    vlmap = FakeVLMap()
    ns = {"vlmap": vlmap}
    before = sha256(project["h5"])
    for code in blocks("python"):
        exec(compile(code, str(DOC), "exec"), ns)
    # block 2: the patched index_map has VLMaps' contract and QuASH's answer
    expected = vlmap.kind == 0
    assert ns["mask"].dtype == bool and ns["mask"].shape == (len(vlmap.grid_feat),)
    np.testing.assert_array_equal(ns["chair_cells"], vlmap.grid_pos[expected])
    np.testing.assert_array_equal(vlmap.get_pos("chair"), vlmap.grid_pos[expected])
    # block 3: sofa through index_map/query
    np.testing.assert_array_equal(index_map(vlmap, "sofa", quash="quash.yaml"), vlmap.kind == 1)
    # "see the queries in Rerun": each step holds what the patched index_map matched
    matched = _rrd_matches(Path("queries.rrd"))
    assert (
        matched["up"] == "+z" and matched["map"] == "voxels map live FakeVLMap object (vlmaps-live)"
    )
    for step, name in enumerate(["chair", "sofa"]):
        assert matched[step] == int(vlmap.index_map(name).sum()) > 0
    # block 4: the saved file
    result = ns["result"]
    np.testing.assert_array_equal(result.mask, project["kind"] == 0)
    assert str(result.n_matched) in capsys.readouterr().out
    # "back to VLMaps' grid": 3D rows are grid_feat's, 2-D rows go back to their cells
    chairs = project["kind"] == 0
    np.testing.assert_array_equal(ns["chair_voxels"], project["grid_pos"][chairs])
    expected_2d = np.zeros(400, bool)
    expected_2d[project["cells"][chairs]] = True
    np.testing.assert_array_equal(ns["cells_2d"], expected_2d.reshape(20, 20))
    assert np.isnan(ns["scores_2d"]).sum() == 400 - 58  # rows 0-1 are zero: unobserved
    assert sha256(project["h5"]) == before
    unpatch_vlmap(vlmap)
    with pytest.raises(AssertionError, match="must not run"):
        vlmap.index_map("chair")


def _rrd_matches(path: Path) -> dict:
    """Per query step, the matched items drawn in ``path``; its up axis and map line."""
    from rerun.chunk import RrdReader

    out: dict = {}
    for chunk in RrdReader(path).stream().to_chunks():
        rb = chunk.to_record_batch()
        names = rb.schema.names
        if chunk.entity_path.startswith("/world/matches/"):
            column = next(n for n in names if n.endswith(":centers") or n.endswith(":positions"))
            for step, items in zip(rb.column("query").to_pylist(), rb.column(column).to_pylist()):
                out[step] = len(items)
        elif chunk.entity_path == "/world" and "ViewCoordinates:xyz" in names:
            up = rb.column("ViewCoordinates:xyz").to_pylist()[0][0]
            out["up"] = "+" + "xyz"[list(up).index(1)]  # Rerun's ViewDir 1 is Up
        elif chunk.entity_path.startswith("/queries/"):
            text = rb.column("TextDocument:text").to_pylist()[0][0]
            out["map"] = text.split("## Map\n\n")[1].split(":")[0].replace("\\", "")
    return out


def test_bash_block_runs(project):
    from quash_plugins.cli.main import main

    for line in blocks("bash")[0].splitlines():
        if line.startswith("quash "):
            assert main(shlex.split(line)[1:]) == 0
    with np.load("chair.npz") as z:
        np.testing.assert_array_equal(z["masks"][0], project["kind"] == 0)


def test_mixin_and_categories(project):
    class MyMap(QuashIndexMixin, FakeVLMap):
        pass

    vlmap = MyMap(seed=3)
    vlmap.quash = "quash.yaml"
    np.testing.assert_array_equal(vlmap.index_map("chair"), vlmap.kind == 0)
    # with categories, the other categories become negatives (VLMaps' argmax rule)
    vlmap.grid_feat[2:6] = np.eye(D)[0] + np.eye(D)[1] * 1.2  # chair beats other, sofa wins
    vlmap.categories = ["chair", "sofa"]
    assert not vlmap.index_map("chair")[2:6].any()
    assert index_map(vlmap, "chair", with_init_cat=False, quash="quash.yaml")[2:6].all()


def test_adapter_section_of_the_config_is_reported_for_a_live_map(project, caplog):
    """A live VLMap takes gs/cs from itself: a config's adapter section that disagrees is
    a warning (once per map), one that agrees or is passed as an option is not."""
    cfg = yaml.safe_load(Path("quash.yaml").read_text())
    cfg["adapter"] = {"name": "vlmaps", "cs": 0.1, "check_finite": False}
    Path("q-cs.yaml").write_text(yaml.safe_dump(cfg))
    vlmap = FakeVLMap()
    before = set(vars(vlmap))
    with caplog.at_level("WARNING", logger="quash_plugins.integrations.vlmaps"):
        index_map(vlmap, "chair", quash="q-cs.yaml")
        index_map(vlmap, "sofa", quash="q-cs.yaml")
    msgs = [r.getMessage() for r in caplog.records if "adapter section" in r.getMessage()]
    assert len(msgs) == 2, msgs  # cs and check_finite, each once
    # what was warned about is remembered beside the map, not on it: unpatch leaves the
    # user's object as it was (a _quash_adapter_warned attribute stayed behind)
    assert set(vars(unpatch_vlmap(vlmap))) == before
    assert any("cs: 0.1" in m and "cs = 0.05" in m for m in msgs)
    assert any("check_finite" in m and "not used" in m for m in msgs)
    caplog.clear()
    cfg["adapter"] = {"name": "vlmaps", "cs": 0.05}
    Path("q-ok.yaml").write_text(yaml.safe_dump(cfg))
    with caplog.at_level("WARNING", logger="quash_plugins.integrations.vlmaps"):
        index_map(FakeVLMap(), "chair", quash="q-ok.yaml")
        index_map(FakeVLMap(), "chair", quash="q-cs.yaml", cs=0.1)  # an option: applied
    assert not [r for r in caplog.records if "(cs: " in r.getMessage()]


def test_quash_query_reads_a_live_vlmap_under_a_config_written_for_files(project, caplog):
    """``Quash.from_config(...).query(vlmap, ...)`` with ``adapter: {name: vlmaps}`` (the
    section-1 config) reads the live object with ``vlmaps-live``, as ``index_map`` does;
    it failed with "--adapter vlmaps-live" and printed the object's arrays. An adapter
    named in the call that cannot read the object is an error worded for a program,
    without the arrays."""
    from types import SimpleNamespace

    from quash_plugins import Quash
    from quash_plugins.core.errors import MapFormatError

    cfg = yaml.safe_load(Path("quash.yaml").read_text())
    cfg["adapter"] = {"name": "vlmaps", "cs": 0.1}
    Path("q-files.yaml").write_text(yaml.safe_dump(cfg))
    vlmap = FakeVLMap(seed=4)
    with caplog.at_level("WARNING"):
        got = Quash.from_config("q-files.yaml").query(vlmap, "chair")
        Quash.from_config("q-files.yaml").query(vlmap, "sofa")
    want = index_map(vlmap, "chair", with_init_cat=False, quash="quash.yaml")
    np.testing.assert_array_equal(got.mask, want)
    assert got.map_source["adapter"] == "vlmaps-live" and got.map_source["cs"] == 0.05
    msgs = [r.getMessage() for r in caplog.records if "adapter section" in r.getMessage()]
    assert len(msgs) == 1 and "cs: 0.1" in msgs[0] and "cs = 0.05" in msgs[0], msgs
    ns = SimpleNamespace(grid_feat=vlmap.grid_feat, grid_pos=vlmap.grid_pos)
    assert Quash.from_config("q-files.yaml").query(ns, "chair", cs=0.1).map_source["cs"] == 0.1
    with pytest.raises(MapFormatError) as err:
        Quash.from_config("q-files.yaml").query(ns, "chair", adapter="vlmaps")
    msg = str(err.value)
    assert "adapter='vlmaps-live'" in msg and "live SimpleNamespace object" in msg
    assert "--adapter" not in msg and "array(" not in msg and len(msg) < 300, msg


def test_a_cell_size_set_anew_on_the_live_map_is_read(project):
    """The live map was cached until its arrays changed: after ``vlmap.cs = 0.1`` (the
    map config's cell_size fixed) every query still placed the objects at cs = 0.05,
    through the drop-in and through ``Quash.query`` alike."""
    from quash_plugins import Quash
    from quash_plugins.integrations.vlmaps import as_latent_map, query

    vlmap, q = FakeVLMap(seed=4), Quash.from_config("quash.yaml")
    assert query(vlmap, "chair", quash=q).map_source["cs"] == 0.05
    assert q.query(vlmap, "chair").map_source["cs"] == 0.05
    before = as_latent_map(vlmap).positions
    vlmap.cs = 0.1
    assert query(vlmap, "chair", quash=q).map_source["cs"] == 0.1
    assert q.query(vlmap, "chair").map_source["cs"] == 0.1
    np.testing.assert_allclose(as_latent_map(vlmap).positions, 2 * before)


def test_a_query_spelled_with_spaces_is_its_underscored_category():
    """VLMaps' category lists spell names with underscores (mp3dcat: ``tv_monitor``,
    ``chest_of_drawers``). The query "tv monitor" was not matched to ``tv_monitor``, so the
    category stayed a negative and took every one of the query's rows: an empty mask."""
    rng = np.random.default_rng(0)
    tv, tv_spaced = np.eye(D)[0], np.eye(D)[0] * 0.95 + np.eye(D)[1] * 0.31
    table = {"tv_monitor": tv, "tv monitor": tv_spaced, "TV-Monitor": tv_spaced}
    table |= {"chair": np.eye(D)[2], "other": np.eye(D)[3]}
    table |= {w: np.eye(D)[4] for w in ("background", "nothing")}
    kind = rng.integers(0, 2, 60)  # 0: a tv_monitor row, 1: a chair row
    feat = np.stack([tv, np.eye(D)[2]])[kind] + rng.normal(0, 0.02, (60, D))
    vlmap = FakeVLMap(n=60)
    vlmap.grid_feat, vlmap.categories = feat.astype(np.float32), ["chair", "tv_monitor"]
    cfg = {
        "encoder": {
            "name": "table",
            "table": {k: np.asarray(v).tolist() for k, v in table.items()},
        },
        "classifier": "contrast",
        "cache": False,
    }
    exact = index_map(vlmap, "tv_monitor", quash=cfg)
    np.testing.assert_array_equal(exact, kind == 0)
    for spelling in ("tv monitor", "TV-Monitor"):
        np.testing.assert_array_equal(index_map(vlmap, spelling, quash=cfg), exact)
    # the category is still a negative of another query
    assert not index_map(vlmap, "chair", quash=cfg)[kind == 0].any()


class _DictConfig(Mapping):
    """OmegaConf's DictConfig as far as the integration can see: a Mapping, not a dict,
    whose sections are DictConfigs and whose lists are ListConfigs (not lists)."""

    def __init__(self, data):
        self._data = data

    def __getitem__(self, key):
        value = self._data[key]
        if isinstance(value, dict):
            return _DictConfig(value)
        return _ListConfig(value) if isinstance(value, list) else value

    def __iter__(self):
        return iter(self._data)

    def __len__(self):
        return len(self._data)


class _ListConfig(Sequence):
    def __init__(self, data):
        self._data = data

    def __getitem__(self, i):
        return self._data[i]

    def __len__(self):
        return len(self._data)


def test_a_hydra_section_is_a_config_and_vlmaps_map_config_is_named(project):
    """VLMaps runs on Hydra: a ``quash:`` section of the project's config is an OmegaConf
    DictConfig, not a dict, and was refused ("quash must be ... a dict"). It is now read
    as the same config; VLMaps' own map config passed by mistake says what it is."""
    from quash_plugins.core.errors import QuashError

    cfg = yaml.safe_load(Path("quash.yaml").read_text())
    cfg["negatives"] = ["other"]  # a ListConfig inside
    vlmap = FakeVLMap(seed=2)
    want = index_map(vlmap, "chair", quash=cfg)
    np.testing.assert_array_equal(index_map(vlmap, "chair", quash=_DictConfig(cfg)), want)
    patch_vlmap(vlmap, _DictConfig(cfg))
    np.testing.assert_array_equal(vlmap.index_map("chair"), want)
    map_config = _DictConfig(
        {"map_type": "vlmap", "grid_size": 1000, "cell_size": 0.05, "pose_info": {}}
    )
    with pytest.raises(QuashError, match=r"VLMaps' map config \(it has cell_size, grid_size"):
        index_map(vlmap, "chair", quash=map_config)


def test_a_hydra_sections_missing_relative_file_names_the_folder_it_was_read_from(project):
    """A ``quash:`` section of a Hydra config naming ``file: labels.yaml`` (kept beside
    the Hydra config) said only 'Taxonomy file not found: labels.yaml': a mapping has no
    folder of its own, so the path is read from the working directory, which it now names
    with the fix."""
    from quash_plugins.core.errors import ConfigError

    cfg = {"encoder": "minilm", "heuristic": {"name": "taxonomy", "file": "labels.yaml"}}
    with pytest.raises(ConfigError) as err:
        patch_vlmap(FakeVLMap(), _DictConfig(cfg))
    msg = " ".join(str(err.value).split())
    assert "Taxonomy file not found: labels.yaml" in msg
    assert f"working directory, {Path.cwd()};" in msg and "give an absolute path" in msg


def test_a_vlmaps_example_config_points_to_a_shipped_config_of_its_own_encoder():
    """examples/configs/vlmaps-contrast.yaml (an LSeg config) sent readers to
    demo-vlmaps.yaml for VLMaps' exact rule: a MiniLM config, which refuses an LSeg map."""
    root = Path(__file__).resolve().parents[2]
    shipped = root / "quash_plugins" / "data" / "configs"
    checked = 0
    for example in sorted((root / "examples" / "configs").glob("vlmaps*.yaml")):
        text = example.read_text(encoding="utf-8")
        encoder = yaml.safe_load(text)["encoder"]
        comments = "\n".join(line for line in text.splitlines() if line.startswith("#"))
        for name in re.findall(r"[\w-]+\.yaml", comments):
            if (shipped / name).exists():
                named = yaml.safe_load((shipped / name).read_text(encoding="utf-8"))
                assert named["encoder"] == encoder, (example.name, name)
                checked += 1
    assert checked


@pytest.mark.parametrize("bad", [["chair", "sofa"], None, 3])
def test_a_query_that_is_not_a_string_is_refused_as_the_pipeline_refuses_it(project, bad):
    """index_map(vlmap, ["chair", "sofa"]) with categories set failed deep in the category
    match ("AttributeError: 'list' object has no attribute 'replace'")."""
    from quash_plugins.core.errors import QuashError

    vlmap = FakeVLMap()
    vlmap.categories = ["chair", "sofa"]
    with pytest.raises(QuashError, match=rf"A query must be a string; got {type(bad).__name__}"):
        index_map(vlmap, bad, quash="quash.yaml")


def test_a_path_in_place_of_the_vlmap_names_the_call_that_reads_a_file(project):
    """query("data/scene/vlmap/vlmaps.h5df", ...) said only that the live adapter reads
    objects, not files: it names the call that reads the file."""
    from quash_plugins.core.errors import MapFormatError

    path = "data/scene/vlmap/vlmaps.h5df"
    with pytest.raises(MapFormatError) as err:
        index_map(path, "chair", quash="quash.yaml")
    said = str(err.value)
    assert said.startswith(f"{path}:") and f"Quash.from_config(CONFIG).query('{path}'" in said
