"""``--quiet`` means one thing on every command: warnings, errors and the command's own
result (the table of ``quash eval``, the answers of ``quash query``), and no line that
only says what was done (``wrote FILE``, ``table NAME: done``). ``quash eval -q --rrd
x.rrd --markdown r.md`` said nothing of the recording and ``wrote r.md`` all the same;
``quash query``, ``convert`` and ``make-scene`` printed their ``wrote`` lines too.

(``quash demo -q``: tests/demo/test_demo.py, a slow test.)
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from quash_plugins.cli.main import main
from quash_plugins.core import registry
from quash_plugins.testing import HashingEncoder

ENCODER = "hashing-quiet"

#: A line that only says what was done: what --quiet leaves out (make-scene's summary,
#: "N voxels, N objects, rooms: ...", among them).
DONE = re.compile(r"^(wrote |streamed to |table \S+: done$|\d+ voxels, \d+ objects, rooms: )")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A tiny generated scene (map, taxonomy, queries), for ``quash bench``."""
    registry.register("encoders", ENCODER, HashingEncoder, replace=True)
    d = tmp_path_factory.mktemp("scene")
    args = ["make-scene", str(d / "scene.npz"), "--encoder", ENCODER, "--no-cache"]
    assert main(["-q", *args, "--rooms", "1", "--voxel-size", "0.25"]) == 0
    yield d / "scene.npz"
    registry.unregister("encoders", ENCODER)


def _case(command: str, world: dict, scene: Path, d: Path) -> tuple[list[str], list[Path], str]:
    """``(argv, files it writes, a piece of its result)`` of ``command``."""
    m, cfg = str(world["map"]), str(world["config"])
    if command == "query":
        files = [d / "r.npz", d / "r.rrd"]
        argv = ["query", m, "chair", "-c", cfg, "--out", str(files[0]), "--rrd", str(files[1])]
        return argv, files, "config vlmaps-contrast"
    if command == "query-zarr":
        files = [d / "r.zarr"]
        return ["query", m, "chair", "-c", cfg, "--out", str(files[0])], files, "chair: "
    if command == "eval":
        files = [d / "r.json", d / "r.md", d / "r.png", d / "r.rrd"]
        flags = ("--json", "--markdown", "--plot", "--rrd")
        argv = ["eval", m, "-c", cfg, "--all-labels"]
        for flag, f in zip(flags, files):
            argv += [flag, str(f)]
        return argv, files, " queries, "
    if command == "convert":
        files = [d / "m.zarr"]
        return ["convert", m, str(files[0])], files, ""
    if command == "make-scene":
        stem = d / "s"
        files = [Path(f"{stem}{x}") for x in (".npz", ".taxonomy.yaml", ".queries.yaml")]
        argv = ["make-scene", str(files[0]), "--encoder", ENCODER, "--no-cache", "--rooms", "1"]
        return argv + ["--voxel-size", "0.25"], files, ""
    if command == "bench":
        files = [d / "b" / "bench.md", d / "b" / "bench.json", d / "b" / "antonyms.png"]
        argv = ["bench", str(scene), "--encoder", ENCODER, "--tables", "antonyms"]
        return argv + ["--no-cache", "--out", str(d / "b")], files, "Antonyms (baseline)"
    raise AssertionError(command)


@pytest.mark.parametrize("quiet", [False, True], ids=["default", "quiet"])
@pytest.mark.parametrize(
    "command", ["query", "query-zarr", "eval", "convert", "make-scene", "bench"]
)
def test_quiet_says_nothing_of_what_was_written(
    command, quiet, tiny_world, scene, tmp_path, monkeypatch, capsys
):
    pytest.importorskip("rerun")
    monkeypatch.setenv("COLUMNS", "1000")  # one line each, no path folded
    argv, files, result = _case(command, tiny_world, scene, tmp_path / "out")
    (tmp_path / "out").mkdir()
    code = main((["-q"] if quiet else []) + argv)
    said = capsys.readouterr()
    assert code == 0, said.err
    done = [ln for ln in (said.out + said.err).splitlines() if DONE.match(ln)]
    for f in files:
        assert f.exists(), f
    if quiet:
        assert done == [], said
        assert not [ln for ln in said.err.splitlines() if ln.startswith("INFO")], said.err
    else:  # said once each, where the file is: on stderr, stdout holds the result
        assert not [ln for ln in said.out.splitlines() if DONE.match(ln)], said.out
        if command == "make-scene":  # its summary, said once, on stderr
            summary = [ln for ln in said.err.splitlines() if " voxels, " in ln]
            assert len(summary) == 1 and DONE.match(summary[0]), said
        wrote = " ".join(ln for ln in done if ln.startswith("wrote "))
        for f in files:
            if command != "bench":  # bench names its folder's files in its tables
                assert wrote.count(f.name) == 1, (f, done)
    assert result in said.out, said.out  # the command's own result, quiet or not


def test_the_help_of_quiet_says_what_still_prints():
    """``-q``'s help said "Only warnings and errors" while the result prints too (the
    rule above): on the main parser and on every subcommand's."""
    from quash_plugins.cli.main import build_parser, subcommand_parsers

    parser = build_parser()
    for p in [parser, *subcommand_parsers(parser).values()]:
        (quiet,) = [a for a in p._actions if "--quiet" in a.option_strings]
        assert "result" in quiet.help and "Only warnings" not in quiet.help, (p.prog, quiet.help)
