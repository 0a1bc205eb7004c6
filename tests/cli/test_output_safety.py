"""``quash query --out`` and ``--rrd`` never replace an input or a user's file.

Each case reproduces an input that used to be replaced (exit 0, data gone): the map
itself (npz and VLMaps h5df), the map through a symbolic or hard link, an existing
file of the user's, a symbolic link, a folder and a device node.
"""

from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest

from quash_plugins.cli.main import main
from quash_plugins.core.atomic import atomic_write, check_output
from quash_plugins.core.errors import UsageError


def _sha(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def world(tiny_world, tmp_path):
    return tiny_world["map"], tiny_world["config"]


def _query(*extra, map_path, config):
    return main(["-q", "query", str(map_path), "chair", "-c", str(config), *map(str, extra)])


def test_out_naming_the_map_is_refused_and_the_map_kept(world, capsys):
    map_path, config = world
    before = _sha(map_path)
    assert _query("--out", map_path, map_path=map_path, config=config) == 2
    assert "is the input" in capsys.readouterr().err
    assert _sha(map_path) == before
    # --force never lets an output replace an input
    assert _query("--out", map_path, "--force", map_path=map_path, config=config) == 2
    assert _sha(map_path) == before


def test_out_through_a_symlink_or_hard_link_to_the_map_is_refused(world, tmp_path, capsys):
    map_path, config = world
    before = _sha(map_path)
    sym = tmp_path / "alias.npz"
    sym.symlink_to(map_path)
    hard = tmp_path / "hard.npz"
    os.link(map_path, hard)
    for out in (sym, hard):
        assert _query("--out", out, "--force", map_path=map_path, config=config) == 2
        assert "is the input" in capsys.readouterr().err
    assert _sha(map_path) == before and sym.is_symlink()


def test_out_naming_a_vlmaps_h5df_map_is_refused(tmp_path, capsys):
    h5py = pytest.importorskip("h5py")
    rng = np.random.default_rng(0)
    path = tmp_path / "vlmaps.h5df"
    with h5py.File(path, "w") as f:
        f["grid_feat"] = rng.normal(size=(20, 4)).astype(np.float32)
        f["grid_pos"] = rng.integers(0, 10, size=(20, 3)).astype(np.int32)
        f["occupied_ids"] = np.full((10, 10, 10), -1, np.int32)
    before = _sha(path)
    code = main(["-q", "query", str(path), "chair", "--out", str(path)])
    assert code == 2 and "is the input" in capsys.readouterr().err
    assert _sha(path) == before


def test_an_existing_file_needs_force_but_a_previous_result_does_not(world, tmp_path, capsys):
    map_path, config = world
    mine = tmp_path / "notes.npz"
    np.savez(mine, important=np.arange(3))
    before = _sha(mine)
    assert _query("--out", mine, map_path=map_path, config=config) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "already exists and is not a previous output of this command" in err
    assert "--force" in err
    assert _sha(mine) == before
    assert _query("--out", mine, "--force", map_path=map_path, config=config) == 0
    with np.load(mine) as z:
        assert {"queries", "masks", "scores", "display_scores"} <= set(z.files)
        assert "important" not in z.files
    # now mine is a previous result: running again replaces it without --force
    assert _query("--out", mine, map_path=map_path, config=config) == 0


@pytest.mark.parametrize("kind", ["symlink", "folder", "device"])
def test_non_regular_targets_are_refused(world, tmp_path, capsys, kind):
    map_path, config = world
    if kind == "symlink":
        target = tmp_path / "elsewhere.npz"
        np.savez(target, x=np.zeros(1))
        out = tmp_path / "link.npz"
        out.symlink_to(target)
        expected = "symbolic link"
    elif kind == "folder":
        out = tmp_path / "dir.npz"
        out.mkdir()
        expected = "is a folder"
    else:
        out = "/dev/null"
        expected = "not a regular file"
    assert _query("--out", out, "--force", map_path=map_path, config=config) == 2
    assert expected in capsys.readouterr().err
    if kind == "device":
        assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")
    if kind == "symlink":
        assert out.is_symlink()


def test_rrd_naming_the_map_is_refused(world, capsys):
    map_path, config = world
    before = _sha(map_path)
    assert _query("--rrd", map_path, map_path=map_path, config=config) == 2
    assert _sha(map_path) == before


def test_rrd_naming_a_file_that_is_no_recording_says_so(world, tmp_path, capsys):
    """--rrd onto a user's file that is not a Rerun recording said only "already exists.
    Pass --force", as if it were an old recording; it says what the file is not."""
    map_path, config = world
    mine = tmp_path / "notes.rrd"
    mine.write_text("my notes\n")
    assert _query("--rrd", mine, map_path=map_path, config=config) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"--rrd {mine} already exists and is not a Rerun recording" in err
    assert "--force" in err
    assert mine.read_text() == "my notes\n"


def test_out_into_an_unwritable_folder_names_the_output(world, tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root can write into any folder")
    map_path, config = world
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    assert _query("--out", ro / "r.npz", map_path=map_path, config=config) == 2
    assert "not writable" in capsys.readouterr().err


def test_atomic_write_refuses_non_regular_targets_whoever_calls_it(tmp_path):
    link = tmp_path / "l"
    link.symlink_to(tmp_path / "missing")
    with pytest.raises(UsageError, match="symbolic link"), atomic_write(link) as tmp:
        tmp.write_text("x")
    assert link.is_symlink() and not (tmp_path / "missing").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["l"]  # no temporary file left


def test_check_output_refuses_outputs_inside_an_input_folder(tmp_path):
    (tmp_path / "pointclouds").mkdir()
    with pytest.raises(UsageError, match="inside the input folder"):
        check_output(tmp_path / "pointclouds" / "r.npz", [tmp_path / "pointclouds"])
    assert check_output(tmp_path / "r.npz", [tmp_path / "pointclouds"]) == tmp_path / "r.npz"


def test_demo_out_that_cannot_be_written_is_an_error_before_any_work(tmp_path, capsys, monkeypatch):
    """``quash demo --out`` in a read-only folder crashed ('unexpected error: OSError')
    after building the scene; it is now refused first, naming --out and the folder."""
    import errno

    from quash_plugins.core import atomic

    real_open = os.open

    def read_only(path, flags, *a):
        if str(path).startswith(str(tmp_path / "ro")):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS))
        return real_open(path, flags, *a)

    monkeypatch.setattr(atomic.os, "open", read_only)
    built = []
    monkeypatch.setattr("quash_plugins.demo.runner.run_demo", lambda **kw: built.append(kw))
    assert main(["demo", "--tiny", "--no-rrd", "--out", str(tmp_path / "ro")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and str(tmp_path / "ro") in err and "Read-only" in err
    assert not built
    assert list((tmp_path / "ro").iterdir()) == []  # the probe left nothing
    # a writable folder passes the check and keeps no probe file
    assert atomic.make_output_folder(tmp_path / "ok" / "sub", "--out").is_dir()
    assert list((tmp_path / "ok" / "sub").iterdir()) == []


def test_files_of_names_and_templates_in_a_config_are_inputs_no_output_may_replace(tmp_path):
    """A label list's ``unlisted`` file, the templates heuristic's template file and
    ``map_negatives``' vocabulary are read from the config's folder: each is an input
    that ``--out``/``--rrd`` must not replace, as ``heuristic.file`` is; the shipped
    names (``vocabulary``, a template list's name) are no file."""
    from quash_plugins.cli._config_opts import input_files
    from quash_plugins.core.config import QuashConfig
    from quash_plugins.core.text import TEMPLATE_NAMES

    (tmp_path / "names.txt").write_text("fireplace\n", encoding="utf-8")
    (tmp_path / "mine.txt").write_text("a photo of {}\n", encoding="utf-8")
    (tmp_path / "vocab.txt").write_text("lamp\n", encoding="utf-8")
    shipped = sorted(TEMPLATE_NAMES)[0]
    p = tmp_path / "c.yaml"
    p.write_text(
        "heuristic: {name: combine, synonyms: {name: taxonomy, unlisted: names.txt},\n"
        "            antonyms: {name: label-list, unlisted: vocabulary}}\n"
        "map_negatives: {n: 3, vocabulary: vocab.txt}\n"
    )
    q = tmp_path / "t.yaml"
    q.write_text("heuristic: {name: templates, templates: mine.txt}\n")
    r = tmp_path / "s.yaml"
    r.write_text(f"heuristic: {{name: templates, templates: {shipped}}}\n")
    found = {
        os.path.realpath(f)
        for f in input_files(None, [QuashConfig.from_yaml(x) for x in (p, q, r)])
    }
    for name in ("names.txt", "mine.txt", "vocab.txt", "c.yaml", "t.yaml", "s.yaml"):
        assert os.path.realpath(tmp_path / name) in found, name
    assert len(found) == 6  # neither 'vocabulary' nor the shipped template list
