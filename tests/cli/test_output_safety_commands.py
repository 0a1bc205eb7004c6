"""Every output of the CLI and the Python writers follows the policy of ``core.atomic``.

An output is never an input (through any link), never a link, device or foreign
folder; an existing file is replaced only when it is a previous output of the same
kind, or with ``--force``. Refusals come before any work. Each case reproduces an
input that used to be replaced.
"""

from __future__ import annotations

import hashlib
import json
import os

import numpy as np
import pytest

from quash_plugins.cli.main import main
from quash_plugins.core.errors import UsageError
from quash_plugins.core.types import LatentMap


def _sha(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def _tree(path) -> dict[str, str]:
    return {str(p.relative_to(path)): _sha(p) for p in sorted(path.rglob("*")) if p.is_file()}


# ---------------------------------------------------------------------- convert
def test_convert_destination_that_is_the_source_through_a_link_is_refused(tiny_world, capsys):
    src = tiny_world["map"]
    before = _sha(src)
    hard = tiny_world["dir"] / "hard.npz"
    os.link(src, hard)
    assert main(["-q", "convert", str(src), str(hard), "--force"]) == 2
    assert "is the input" in capsys.readouterr().err
    assert _sha(src) == before


def test_convert_existing_destination_needs_force(tiny_world, tmp_path, capsys):
    mine = tmp_path / "mine.npz"
    np.savez(mine, embeddings=np.eye(3, dtype=np.float32))
    before = _sha(mine)
    assert main(["-q", "convert", str(tiny_world["map"]), str(mine)]) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and "--force" in err
    assert _sha(mine) == before
    assert main(["-q", "convert", str(tiny_world["map"]), str(mine), "--force"]) == 0
    with np.load(mine) as z:
        assert z["embeddings"].shape == (600, 16)


def test_convert_never_replaces_a_folder_that_is_not_a_zarr_store(tiny_world, tmp_path, capsys):
    pytest.importorskip("zarr")
    folder = tmp_path / "photos.zarr"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"precious")
    for extra in ([], ["--force"]):
        assert main(["-q", "convert", str(tiny_world["map"]), str(folder), *extra]) == 2
        assert "neither a zarr store" in capsys.readouterr().err
    assert (folder / "holiday.jpg").read_bytes() == b"precious"
    # a zarr store written by convert is replaced with --force
    store = tmp_path / "m.zarr"
    assert main(["-q", "convert", str(tiny_world["map"]), str(store)]) == 0
    assert main(["-q", "convert", str(tiny_world["map"]), str(store)]) == 2
    assert main(["-q", "convert", str(tiny_world["map"]), str(store), "--force"]) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ---------------------------------------------------------------------- eval
def _eval(world, *extra):
    return main(["-q", "eval", str(world["map"]), "-c", str(world["config"]), *map(str, extra)])


def test_eval_outputs_never_replace_the_map_or_the_config(tiny_world, capsys):
    for flag, target in (("--json", "map"), ("--markdown", "config"), ("--plot", "map")):
        before = _sha(tiny_world[target])
        assert _eval(tiny_world, flag, tiny_world[target], "--force") == 2
        assert "is the input" in capsys.readouterr().err
        assert _sha(tiny_world[target]) == before


def test_eval_outputs_need_force_unless_previous_reports(tiny_world, tmp_path, capsys):
    js, md, png = tmp_path / "notes.json", tmp_path / "notes.md", tmp_path / "photo.png"
    js.write_text('{"mine": 1}')
    md.write_text("my notes\n")
    png.write_bytes(b"\x89PNG\r\n\x1a\nnot a quash plot")
    before = {p: _sha(p) for p in (js, md, png)}
    for flag, path in (("--json", js), ("--markdown", md), ("--plot", png)):
        assert _eval(tiny_world, flag, path) == 2
        assert "already exists" in capsys.readouterr().err
    assert {p: _sha(p) for p in (js, md, png)} == before
    assert _eval(tiny_world, "--json", js, "--markdown", md, "--plot", png, "--force") == 0
    assert "configs" in json.loads(js.read_text())
    # now they are previous reports: a re-run replaces them without --force
    assert _eval(tiny_world, "--json", js, "--markdown", md, "--plot", png) == 0
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_eval_outputs_onto_a_folder_or_the_same_file_are_refused(tiny_world, tmp_path, capsys):
    (tmp_path / "d.json").mkdir()
    assert _eval(tiny_world, "--json", tmp_path / "d.json") == 2
    assert "is a folder" in capsys.readouterr().err
    same = tmp_path / "r.json"
    assert _eval(tiny_world, "--json", same, "--markdown", same) == 2
    err = capsys.readouterr().err
    assert "--json" in err and "--markdown" in err and "name the same file" in err


def test_eval_outputs_naming_one_file_through_a_link_or_a_relative_path_are_refused(
    tiny_world, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    link = tmp_path / "link.json"
    link.symlink_to(tmp_path / "r.json")
    for a, b in (("r.json", link), ("r.json", tmp_path / "sub" / ".." / "r.json")):
        assert _eval(tiny_world, "--json", a, "--plot", b, "--force") == 2
        err = capsys.readouterr().err
        assert "--json" in err and "--plot" in err and "name the same file" in err
    assert not (tmp_path / "r.json").exists()


# ---------------------------------------------------------------------- query
def test_query_out_and_rrd_naming_one_file_are_refused_before_any_work(
    tiny_world, tmp_path, capsys, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    m, c = str(tiny_world["map"]), str(tiny_world["config"])
    (tmp_path / "d").mkdir()
    for out, rrd in (
        ("same.rrd", "same.rrd"),
        ("same.rrd", str(tmp_path / "d" / ".." / "same.rrd")),
    ):
        assert main(["-q", "query", m, "chair", "-c", c, "--out", out, "--rrd", rrd]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and "--rrd" in err and "name the same file" in err
        assert "wrote" not in err
    assert not (tmp_path / "same.rrd").exists()


def test_an_openlex3d_results_folder_holding_a_users_file_is_never_replaced(
    tiny_world, tmp_path, capsys
):
    """Replacing a previous --format openlex3d folder deleted every other file in it (a
    recording, notes). A folder holding anything but the writer's files is not a
    previous output; --rrd inside a folder --out is refused before any work."""
    pytest.importorskip("open3d")
    m, c = str(tiny_world["map"]), str(tiny_world["config"])
    out = tmp_path / "ol"
    base = ["-q", "query", m, "chair", "-c", c, "--out", str(out), "--format", "openlex3d"]
    assert main(base) == 0
    assert main([*base, "--force"]) == 0  # a previous output, as written: replaced
    assert main([*base[:3], "sofa", *base[4:]]) == 0
    assert json.loads((out / "queries.json").read_text())["queries"][0]["query_text"] == "sofa"
    capsys.readouterr()
    # a recording inside the folder: refused, whichever is named first
    assert main([*base, "--rrd", str(out / "q.rrd")]) == 2
    assert "is inside --out" in capsys.readouterr().err
    (out / "notes.txt").write_text("mine")
    before = _tree(out)
    for extra in ([], ["--force"]):
        assert main([*base, *extra]) == 2
        assert "nor a previous output" in capsys.readouterr().err
        assert _tree(out) == before  # the notes and the results, untouched


def test_query_format_without_out_and_two_configs_are_refused(tiny_world, capsys):
    m, c = str(tiny_world["map"]), str(tiny_world["config"])
    with pytest.raises(SystemExit) as exc:
        main(["-q", "query", m, "chair", "-c", c, "-c", "demo:quash-labels"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "-c is given twice" in err and "quash eval" in err
    assert main(["-q", "query", m, "chair", "-c", c, "--format", "openlex3d"]) == 2
    assert "give --out too" in capsys.readouterr().err


def test_outputs_never_replace_the_taxonomy_beside_the_map_or_a_file_the_config_names(
    tiny_world, capsys
):
    """The taxonomy heuristics read MAP.taxonomy.yaml; the config names its encoder's
    table. Neither is replaced, even with --force."""
    taxonomy = tiny_world["map"].with_name("map.taxonomy.yaml")
    taxonomy.write_text("chair: [armchair]\n")
    table = tiny_world["dir"] / "text.npz"
    before = {p: _sha(p) for p in (taxonomy, table)}
    m, c = str(tiny_world["map"]), str(tiny_world["config"])
    for target in (taxonomy, table):
        assert main(["-q", "query", m, "chair", "-c", c, "--out", str(target), "--force"]) == 2
        assert "is the input" in capsys.readouterr().err
        assert _eval(tiny_world, "--json", target, "--force") == 2
        assert "is the input" in capsys.readouterr().err
    assert {p: _sha(p) for p in (taxonomy, table)} == before


# ---------------------------------------------------------------------- bench, demo
def test_bench_refuses_foreign_files_in_out_before_any_work(tiny_world, tmp_path, capsys):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.md").write_text("my own notes\n")
    assert main(["-q", "bench", str(tiny_world["map"]), "--out", str(out)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert (out / "bench.md").read_text() == "my own notes\n"
    afile = tmp_path / "afile"
    afile.write_text("x")
    assert main(["-q", "bench", str(tiny_world["map"]), "--out", str(afile)]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_demo_refuses_foreign_files_in_out_before_any_work(tmp_path, capsys):
    out = tmp_path / "d"
    out.mkdir()
    (out / "demo.json").write_text('{"mine": true}')
    (out / "demo.rrd").write_text("not a recording")
    assert main(["-q", "demo", "--tiny", "--out", str(out)]) == 2
    assert "demo.json already exists" in capsys.readouterr().err
    assert main(["-q", "demo", "--tiny", "--out", str(out), "--no-rrd"]) == 2
    (out / "demo.json").unlink()
    assert main(["-q", "demo", "--tiny", "--out", str(out)]) == 2
    assert "--rrd" in capsys.readouterr().err
    assert (out / "demo.rrd").read_text() == "not a recording"


def test_demo_rrd_naming_one_of_its_reports_is_refused(tmp_path, capsys):
    out = tmp_path / "d"
    assert main(["-q", "demo", "--tiny", "--out", str(out), "--rrd", str(out / "demo.md")]) == 2
    err = capsys.readouterr().err
    assert "--rrd" in err and "demo.md" in err and "name the same file" in err
    assert not out.exists()


def test_demo_without_the_rerun_sdk_says_to_pass_no_rrd(tmp_path, capsys, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "rerun", None)  # import rerun raises ImportError
    out = tmp_path / "d"
    assert main(["-q", "demo", "--tiny", "--out", str(out)]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "quash-plugins[rerun]" in err and "--no-rrd" in err and "demo.rrd" in err
    assert not out.exists()  # refused before any work


# ---------------------------------------------------------------------- make-scene
def test_make_scene_refuses_a_users_map_and_yaml(tiny_world, tmp_path, capsys):
    target = tmp_path / "scene.npz"
    target.write_bytes(tiny_world["map"].read_bytes())
    before = _sha(target)
    assert main(["-q", "make-scene", str(target)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert _sha(target) == before
    target.unlink()
    (tmp_path / "scene.queries.yaml").write_text("my: notes\n")
    assert main(["-q", "make-scene", str(target)]) == 2
    assert (tmp_path / "scene.queries.yaml").read_text() == "my: notes\n"


def test_make_scene_outputs_are_recognised_as_previous_ones(tmp_path):
    from quash_plugins.demo.scene import Scene, is_scene_file, scene_paths, write_scene

    m = LatentMap(np.eye(3, dtype=np.float32), labels=np.arange(3), label_names=["a", "b", "c"])
    paths = write_scene(Scene(m, {"a": ["x"]}, ["z"], ["kitchen"], 3), tmp_path / "s.npz")
    assert paths == scene_paths(tmp_path / "s.npz")
    assert all(is_scene_file(p) for p in paths.values())
    np.savez(tmp_path / "other.npz", embeddings=np.eye(2))
    assert not is_scene_file(tmp_path / "other.npz")


# ---------------------------------------------------------------------- files read with the map
@pytest.fixture
def vlmaps_scene(tmp_path):
    """A VLMaps map with ground truth, the scene's ``obj2cls_dict.txt`` that names its
    classes (read beside the map, not named on the command line), and a config."""
    from _cf_writers import contrast_config, text_table
    from _vlmaps_writers import mobile_map, write_vlmaps_h5df

    h5 = write_vlmaps_h5df(
        tmp_path / "scene" / "vlmap" / "vlmaps.h5df", mobile_map(d=8), semantic=np.arange(50) % 3
    )
    names = tmp_path / "scene" / "obj2cls_dict.txt"
    names.write_text("0: 0, chair\n1: 1, sofa\n2: 2, table\n")
    table, _ = text_table(tmp_path, 8)
    return {"map": h5, "names": names, "config": contrast_config(tmp_path, table)}


def test_query_and_eval_never_replace_a_file_read_beside_the_map(vlmaps_scene, tmp_path, capsys):
    """Refused once the map is read, before any query runs, even with --force."""
    world, names = vlmaps_scene, vlmaps_scene["names"]
    before = _sha(names)
    query = ["-q", "query", str(world["map"]), "chair", "-c", str(world["config"])]
    assert main([*query, "--out", str(names), "--format", "npz", "--force"]) == 2
    err = capsys.readouterr().err
    assert f"--out {names} is the input {names}" in err and "Choose another" in err
    for flag in ("--json", "--markdown", "--plot"):
        assert _eval(world, flag, names, "--force") == 2
        assert f"{flag} {names} is the input {names}" in capsys.readouterr().err
    assert _sha(names) == before
    assert main([*query, "--out", str(tmp_path / "r.npz")]) == 0
    assert _eval(world, "--json", tmp_path / "r.json") == 0


# ---------------------------------------------------------------------- Python writers
def test_write_results_npz_refuses_the_results_own_map(tiny_world, tmp_path):
    from quash_plugins import Quash
    from quash_plugins.engine.results import write_results_npz

    map_path = tiny_world["map"]
    before = _sha(map_path)
    results = Quash.from_config(tiny_world["config"]).query_many(map_path, ["chair"])
    link = tmp_path / "link.npz"
    link.symlink_to(map_path)
    for target in (map_path, link):
        with pytest.raises(UsageError):
            write_results_npz(target, results)
    assert _sha(map_path) == before
    assert write_results_npz(tmp_path / "r.npz", results).exists()


def test_npz_and_zarr_writers_refuse_their_own_source(tiny_world, tmp_path):
    pytest.importorskip("zarr")
    from quash_plugins.adapters import read_map, write_npz_map, write_zarr_map

    lmap = read_map(tiny_world["map"])
    before = _sha(tiny_world["map"])
    with pytest.raises(UsageError, match="is the input"):
        write_npz_map(lmap, tiny_world["map"])
    assert _sha(tiny_world["map"]) == before
    store = write_zarr_map(lmap, tmp_path / "m.zarr")
    zmap = read_map(store)
    snapshot = _tree(store)
    with pytest.raises(UsageError, match="is the input"):
        write_zarr_map(zmap, store)
    assert _tree(store) == snapshot
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep")
    with pytest.raises(UsageError, match="neither a zarr store"):
        write_zarr_map(lmap, folder)
    assert (folder / "keep.txt").read_text() == "keep"


def test_atomic_dir_puts_the_old_store_back_when_the_swap_fails(tmp_path, monkeypatch):
    from quash_plugins.core import atomic

    store = tmp_path / "s.zarr"
    store.mkdir()
    (store / "zarr.json").write_text("{}")
    real = os.replace
    calls = []

    def flaky(a, b):
        calls.append((a, b))
        if len(calls) == 2:  # the old store is aside, the new one not yet in place
            raise KeyboardInterrupt
        return real(a, b)

    monkeypatch.setattr(atomic.os, "replace", flaky)
    with pytest.raises(KeyboardInterrupt), atomic.atomic_dir(store) as tmp:
        tmp.mkdir()
        (tmp / "zarr.json").write_text('{"new": 1}')
    assert (store / "zarr.json").read_text() == "{}"
    assert [p.name for p in tmp_path.iterdir()] == ["s.zarr"]


# ---------------------------------------------------------------------- caches
def test_links_and_pipes_planted_in_the_caches_are_never_followed(tmp_path, caplog):
    from quash_plugins.engine.cache import TextEmbeddingCache, _safe_name, _shard_of
    from quash_plugins.heuristics._llm import LLMHeuristic

    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    cache = TextEmbeddingCache(tmp_path / "emb")
    folder = cache.root / _safe_name("enc")
    folder.mkdir(parents=True)
    (folder / f"{_shard_of('chair')}.npz").symlink_to(victim)
    os.mkfifo(folder / f"{_shard_of('sofa')}.npz")  # reading it would block forever
    cache.store("enc", {"chair": np.ones(2, np.float32), "sofa": np.ones(2, np.float32)})
    assert set(cache.lookup("enc", ["chair", "sofa"])) <= {"chair", "sofa"}
    assert victim.read_text() == "keep"
    llm = LLMHeuristic(model="m", offline=True, cache_dir=str(tmp_path / "llm"))
    path = llm.cache_path("chair")
    path.parent.mkdir(parents=True)
    path.symlink_to(victim)
    assert llm._read_cache("chair") is None
    llm._write_cache("chair", ["seat"], ["lamp"])
    assert victim.read_text() == "keep" and path.is_symlink()
    assert "not a regular file" in caplog.text and "not cached" in caplog.text


def test_an_empty_folder_may_be_replaced_by_a_store(tiny_world, tmp_path):
    pytest.importorskip("zarr")
    empty = tmp_path / "m.zarr"
    empty.mkdir()  # nothing in it to lose
    assert main(["-q", "convert", str(tiny_world["map"]), str(empty)]) == 0
    assert (empty / "zarr.json").is_file()
