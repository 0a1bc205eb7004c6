"""The CLI as a user meets it: exit codes, messages without tracebacks, outputs."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

from quash_plugins import __version__
from quash_plugins.cli.main import main
from quash_plugins.core.errors import MapFormatError


def run_cli(*args, capsys):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def query_chair(world, *extra, capsys, config=None):
    """``quash query MAP chair -c CONFIG *extra`` on the tiny world: (code, out, err)."""
    return run_cli(
        "query", world["map"], "chair", "-c", config or world["config"], *extra, capsys=capsys
    )


def test_help_for_every_subcommand(capsys):
    from quash_plugins.cli.main import _commands

    for mod in _commands():
        with pytest.raises(SystemExit) as exc:
            main([mod.NAME, "--help"])
        assert exc.value.code == 0
        assert mod.NAME in capsys.readouterr().out


def test_no_command_prints_help_and_exits_2(capsys):
    code, out, _ = run_cli(capsys=capsys)
    assert code == 2 and "COMMAND" in out


def test_query_writes_masks_and_scores(tiny_world, tmp_path, capsys):
    out_path = tmp_path / "result.npz"
    code, out, err = run_cli(
        "query",
        tiny_world["map"],
        "chair",
        "sofa",
        "-c",
        tiny_world["config"],
        "--out",
        out_path,
        capsys=capsys,
    )
    assert code == 0, err
    assert "chair" in out and "sofa" in out
    with np.load(out_path, allow_pickle=False) as z:
        assert z["queries"].tolist() == ["chair", "sofa"]
        assert z["masks"].shape == (2, 600) and z["masks"].dtype == bool
        assert z["scores"].shape == (2, 600) and z["scores"].dtype == np.float32
        assert (z["masks"] == (z["scores"] > 0)).all()
    assert not list(tmp_path.glob(".result.npz*")), "no temporary file may be left behind"


def test_query_json_summary(tiny_world, capsys):
    code, out, _ = run_cli(
        "query",
        tiny_world["map"],
        "chair",
        "-c",
        tiny_world["config"],
        "--json",
        "--adapter",
        "npz",
        capsys=capsys,
    )
    assert code == 0
    data = json.loads(out)
    assert data["n"] == 600 and data["results"][0]["query"] == "chair"
    assert 0 < data["results"][0]["matched"] < 600


def test_query_timings_count_the_map_read_by_the_command(tiny_world, capsys, monkeypatch):
    """quash query reads the map before query_many, which then found it read: the
    table said 'read* 0.0' ms whatever the read cost. The command's own read is shown."""
    import time

    from quash_plugins.core import maps

    read = maps.read_map

    def slow_read(*args, **kwargs):  # the adapter's read of the file, not the cache's
        time.sleep(0.2)
        return read(*args, **kwargs)

    monkeypatch.setattr(maps, "read_map", slow_read)
    code, out, _ = run_cli(
        "query", tiny_world["map"], "chair", "sofa", "-c", tiny_world["config"], capsys=capsys
    )
    assert code == 0
    shown = float(re.search(r"read\*\s+([0-9.]+)", out).group(1))
    assert shown >= 100.0  # ms per query: its share of the 200 ms read, split over two


def test_the_packages_warnings_print_as_log_lines():
    """Not Python's '/path/to/quash_plugins/cli/cmd_query.py:108: EmptyMapWarning: ...',
    which points at our code; other warnings keep Python's format."""
    import warnings

    from quash_plugins.cli._output import setup_logging
    from quash_plugins.core.errors import EmptyMapWarning

    setup_logging(0, False)
    own = warnings.formatwarning("m.npz is empty", EmptyMapWarning, "/x/cmd_query.py", 108)
    assert own == "WARNING  m.npz is empty\n"
    other = warnings.formatwarning("careful", UserWarning, "/x/y.py", 3)
    assert "/x/y.py:3: UserWarning: careful" in other
    setup_logging(0, False)  # installed once: the default is kept, not wrapped again
    assert "/x/y.py:3" in warnings.formatwarning("careful", UserWarning, "/x/y.py", 3)


def test_expand_warns_when_the_map_does_not_fit_the_encoder(tiny_world, capsys):
    """A 16-d map given to quash expand with MiniLM (384-d): the expansion goes on, and
    says that a query with this config on that map would stop."""
    pytest.importorskip("sentence_transformers")
    code, out, err = run_cli(
        "expand", "chair", "--map", tiny_world["map"], "-c", "demo:quash-labels", capsys=capsys
    )
    assert code == 0 and "positives" in out
    warned = " ".join(err.split())  # one log record, however the terminal wraps it
    assert "16-dimensional embeddings" in warned
    assert "quash query with this config on this map stops here" in warned


def test_expand_json(tiny_world, capsys):
    code, out, _ = run_cli("expand", "chair", "-c", tiny_world["config"], "--json", capsys=capsys)
    assert code == 0
    data = json.loads(out)
    assert set(data) == {"query", "positives", "negatives", "provenance"}
    assert data["positives"] == ["chair"] and data["negatives"] == [
        "other",
        "background",
        "nothing",
    ]


def test_plugins_json_lists_distribution_and_status(capsys):
    code, out, _ = run_cli("plugins", "--json", capsys=capsys)
    assert code == 0
    rows = json.loads(out)
    byname = {(r["kind"], r["name"]): r for r in rows}
    row = byname[("classifiers", "svm-rbf")]
    assert row["distribution"] == "quash-plugins" and row["status"] == "ok" and row["version"]


def test_plugins_json_stays_json_when_a_plugin_prints_as_it_is_imported(capsys):
    """A plugin module that prints a banner when imported wrote it into the JSON on
    stdout, which then did not parse; it goes to stderr."""
    from quash_plugins import Encoder
    from quash_plugins.core import _entry_points, registry
    from quash_plugins.core._entry_points import PluginInfo

    class Chatty(Encoder):
        dim = 4

        def encode_text(self, texts):  # pragma: no cover - not called
            raise AssertionError

    def load():
        print("chatty: loading its weights index")
        return Chatty

    registry.available("encoders")  # scanned
    info = PluginInfo("encoders", "chatty", "chatty:Chatty", "pkg-chatty", "0.1", _loader=load)
    _entry_points._scanned["encoders"].append(info)
    try:
        code, out, err = run_cli("plugins", "--kind", "encoders", "--json", capsys=capsys)
    finally:
        _entry_points._scanned["encoders"].remove(info)
    assert code == 0
    rows = {r["name"]: r for r in json.loads(out)}
    assert rows["chatty"]["status"] == "ok"
    assert "chatty: loading its weights index" in err


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.mark.parametrize(
    "case",
    [
        "missing_map",
        "unknown_plugin",
        "malformed_yaml",
        "empty_query",
        "nan",
        "bad_param",
        "dimension",
        "missing_config",
    ],
)
def test_bad_input_clear_message_no_traceback(case, tiny_world, tmp_path, capsys):
    map_path, cfg = tiny_world["map"], tiny_world["config"]
    args = ["query", map_path, "chair", "-c", cfg]
    expect = ""
    if case == "missing_map":
        args[1] = tmp_path / "nope.npz"
        expect = "Map not found"
    elif case == "unknown_plugin":
        cfg = tmp_path / "u.yaml"
        cfg.write_text(f"encoder: {{name: table, file: {tiny_world['table']}}}\nheuristic: llmm\n")
        args[4] = cfg
        expect = "'llmm' is not registered"
    elif case == "malformed_yaml":
        cfg = tmp_path / "m.yaml"
        cfg.write_text("encoder: [table\n")
        args[4] = cfg
        expect = f"{cfg}:"
    elif case == "empty_query":
        args[2] = "  "
        expect = "query is empty"
    elif case == "nan":
        bad = tmp_path / "nan.npz"
        E = tiny_world["E"].copy()
        E[5, 0] = np.nan
        np.savez(bad, embeddings=E)
        args[1] = bad
        expect = "NaN"
    elif case == "bad_param":
        cfg = tmp_path / "p.yaml"
        cfg.write_text(
            f"encoder: {{name: table, file: {tiny_world['table']}}}\n"
            "classifier: {name: svm-rbf, gama: 2}\n"
        )
        args[4] = cfg
        expect = "'gama'"
    elif case == "dimension":
        bad = tmp_path / "wide.npz"
        np.savez(bad, embeddings=np.ones((5, 512), np.float32))
        args[1] = bad
        expect = "512"
    elif case == "missing_config":
        args[4] = tmp_path / "nope.yaml"
        expect = "Config file not found"
    before = _digest(map_path)
    code, out, err = run_cli(*args, capsys=capsys)
    assert code == (2 if case == "missing_config" else 1), err
    assert expect in err
    assert "Traceback" not in err and "Traceback" not in out
    assert _digest(map_path) == before


def _console_script() -> Path:
    """The installed ``quash`` script: the one pip generated from the entry point."""
    (ep,) = entry_points(group="console_scripts", name="quash")
    assert ep.value == "quash_plugins.cli.main:main"
    script = Path(sys.executable).parent / ("quash.exe" if os.name == "nt" else "quash")
    assert script.exists(), f"{script} missing: install the package (pip install -e .)"
    return script


def test_console_script_entry_point(tiny_world):
    """The ``quash`` command itself, as a user runs it, not ``python -m``."""
    script = _console_script()
    exe = subprocess.run([str(script), "--version"], capture_output=True, text=True)
    assert exe.returncode == 0 and exe.stdout.strip() == f"quash-plugins {__version__}"
    exe = subprocess.run(
        [
            str(script),
            "query",
            str(tiny_world["map"]),
            "chair",
            "-c",
            str(tiny_world["config"]),
            "--json",
        ],
        capture_output=True,
        text=True,
        cwd=tiny_world["dir"],
    )
    assert exe.returncode == 0, exe.stderr
    assert json.loads(exe.stdout)["results"][0]["query"] == "chair"


def test_python_dash_m_runs_the_same_command(tmp_path):
    """``python -m quash_plugins`` where the ``quash`` script is not on the PATH."""
    run = [sys.executable, "-m", "quash_plugins"]
    exe = subprocess.run([*run, "--version"], capture_output=True, text=True)
    assert exe.returncode == 0 and exe.stdout.strip() == f"quash-plugins {__version__}"
    bad = subprocess.run(
        [*run, "query", str(tmp_path / "nope.npz"), "x"], capture_output=True, text=True
    )
    assert bad.returncode == 1 and "Map not found" in bad.stderr


def test_debug_shows_traceback(tmp_path):
    """Without --debug: one line, no traceback. With it: Python's traceback through the
    package, ending in the error the user caused."""
    script = _console_script()
    args = [str(script), "query", str(tmp_path / "nope.npz"), "chair"]
    plain = subprocess.run(args, capture_output=True, text=True)
    assert plain.returncode == 1
    assert "Traceback" not in plain.stderr
    assert plain.stderr.strip().splitlines() == [
        f"quash query: error: Map not found: {tmp_path / 'nope.npz'}. Check the path."
    ]
    debug = subprocess.run([*args, "--debug"], capture_output=True, text=True)
    assert debug.returncode == 1
    err = debug.stderr
    assert err.startswith("Traceback (most recent call last):"), err
    assert re.search(r'File ".*quash_plugins[/\\]cli[/\\]main\.py", line \d+, in main', err)
    assert re.search(
        r'File ".*quash_plugins[/\\]core[/\\]maps\.py", line \d+, in (read_map|resolve_adapter)',
        err,
    )
    assert (
        err.strip()
        .splitlines()[-1]
        .endswith(f"MapFormatError: Map not found: {tmp_path / 'nope.npz'}. Check the path.")
    )
    # in-process, --debug lets the error itself propagate (for debuggers and notebooks)
    with pytest.raises(MapFormatError, match="Map not found"):
        main(["query", str(tmp_path / "nope.npz"), "chair", "--debug"])


@pytest.mark.parametrize("where", ["before", "after"])
def test_output_options_work_before_and_after_the_command(tmp_path, where):
    """``quash --debug query ...`` and ``quash query ... --debug`` both raise (the global
    options that ``quash --help`` lists must not be reset by the subcommand's parser)."""
    cmd = ["query", str(tmp_path / "nope.npz"), "chair"]
    argv = ["--debug", *cmd] if where == "before" else [*cmd, "--debug"]
    with pytest.raises(MapFormatError, match="Map not found"):
        main(argv)
    from quash_plugins.cli.main import build_parser

    flags = ["-q", "-vv"]
    ns = build_parser().parse_args(
        [*flags, "plugins"] if where == "before" else ["plugins", *flags]
    )
    assert (ns.quiet, ns.verbose, ns.debug) == (True, 2, False)


def _npz_and_zarr(map_path, queries, config, tmp_path, capsys):
    """``quash query`` with ``--out r.npz``, then ``--out r.zarr --json``: the npz arrays,
    the zarr store and the printed results."""
    zarr = pytest.importorskip("zarr")
    args = ("query", map_path, *queries, "-c", config)
    code, _, err = run_cli(*args, "--out", tmp_path / "r.npz", capsys=capsys)
    assert code == 0, err
    code, out, err = run_cli(*args, "--out", tmp_path / "r.zarr", "--json", capsys=capsys)
    assert code == 0, err
    with np.load(tmp_path / "r.npz") as z:
        npz = {k: z[k] for k in ("masks", "scores")}
    return npz, zarr.open_group(str(tmp_path / "r.zarr"), mode="r"), json.loads(out)


def test_query_out_zarr_streams_same_results(tiny_world, tmp_path, capsys):
    npz, store, doc = _npz_and_zarr(
        tiny_world["map"], ["chair", "sofa"], tiny_world["config"], tmp_path, capsys
    )
    np.testing.assert_array_equal(np.asarray(store["masks"]), npz["masks"])
    np.testing.assert_allclose(np.asarray(store["scores"]), npz["scores"], atol=1e-5)
    assert [r["matched"] for r in doc["results"]] == npz["masks"].sum(1).tolist()


def test_query_out_zarr_applies_refine_and_presence(minilm_scene, tmp_path, capsys):
    """With the shipped refine + presence config, --out r.zarr holds --out r.npz's masks
    and scores bit for bit (one group: the same code on the same classifiers), so an
    absent object comes back empty in both; the map is untouched."""
    before = hashlib.sha256(minilm_scene.read_bytes()).hexdigest()
    queries = ["chair", "piano"]  # piano: only the taxonomy knows it, never in the scene
    npz, store, doc = _npz_and_zarr(minilm_scene, queries, "demo:quash-labels", tmp_path, capsys)
    assert hashlib.sha256(minilm_scene.read_bytes()).hexdigest() == before
    np.testing.assert_array_equal(np.asarray(store["masks"]), npz["masks"])
    np.testing.assert_array_equal(np.asarray(store["scores"]), npz["scores"])
    matched = [r["matched"] for r in doc["results"]]
    assert matched == npz["masks"].sum(1).tolist() and matched[0] > 0 and matched[1] == 0
    presence = [s["provenance"]["presence"]["present"] for s in store.attrs["querysets"]]
    assert presence == [True, False]
    # the printed decision, as the .npz report gives it
    said = [r["presence"] for r in doc["results"]]
    assert said[0].startswith("present (") and said[1].startswith("absent: ")


def test_reader_that_hangs_up_is_not_an_error():
    """``quash plugins --json | head -1``: the reader closes the pipe early. Before, the
    command printed "unexpected error: BrokenPipeError" on stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "quash_plugins.cli.main", "plugins", "--json"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    proc.stdout.close()  # hang up before it writes anything
    err = proc.stderr.read().decode()
    proc.stderr.close()
    assert proc.wait(timeout=120) == 141
    assert "BrokenPipe" not in err and "unexpected error" not in err, err


@pytest.mark.parametrize(
    ("option", "value", "said"),
    [
        ("--bind", "999.0.0.1", "is not an IP address"),
        ("--bind", "myhost", "is not an IP address"),
        ("--web-port", "70000", "from 1 to 65535"),
        ("--grpc-port", "0", "from 1 to 65535"),
        ("--grpc-port", "-1", "from 1 to 65535"),
    ],
)
def test_viewer_address_and_ports_are_checked_when_parsed(option, value, said, tmp_path, capsys):
    """A host name or an out-of-range port is a usage error naming the option, not an
    'unexpected error' from the socket layer nor a silent default (grpc-port 0)."""
    argv = ["query", str(tmp_path / "m.npz"), "chair", "--serve-web", option, value]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"argument {option}" in err and said in err and "unexpected" not in err


def test_viewer_bind_localhost_is_the_loopback_address():
    from quash_plugins.cli.main import build_parser

    ns = build_parser().parse_args(["query", "m.npz", "chair", "--bind", "localhost"])
    assert ns.bind == "127.0.0.1"
    ns = build_parser().parse_args(
        ["query", "m.npz", "chair", "--bind", "10.0.0.1", "--web-port", "1"]
    )
    assert (ns.bind, ns.web_port) == ("10.0.0.1", 1)
    # IPv6 got past the parser and failed in Rerun as an 'unexpected error'
    with pytest.raises(SystemExit):
        build_parser().parse_args(["query", "m.npz", "chair", "--bind", "::1"])


def test_serving_on_one_port_for_both_servers_is_refused_before_any_work(tiny_world, capsys):
    code, _, err = query_chair(
        tiny_world, "--serve-web", "--web-port", "9090", "--grpc-port", "9090", capsys=capsys
    )
    assert code == 2 and "need a port each" in err and "read" not in err


@pytest.mark.parametrize(
    ("flags", "said"),
    [
        (["--bind", "0.0.0.0"], "--bind only applies to --serve-web"),
        (["--web-port", "9191"], "--web-port only applies to --serve-web"),
        (["--grpc-port", "9977", "--bind", "127.0.0.1"], "--grpc-port and --bind only apply"),
    ],
)
def test_serving_flags_without_serve_web_are_refused(flags, said, tiny_world, capsys):
    """They used to be ignored without a word: --bind 0.0.0.0 served nothing and said so
    to no one."""
    code, out, err = query_chair(tiny_world, *flags, capsys=capsys)
    assert code == 2 and said in err and "Add --serve-web" in err
    assert "chair" not in out  # refused before any work


@pytest.mark.parametrize(
    ("bind", "warned"),
    [("127.0.0.1", False), ("127.0.0.2", False), ("0.0.0.0", True), ("192.0.2.7", True)],
)
def test_serving_beyond_loopback_is_warned_about(bind, warned, caplog):
    from quash_plugins.viewer._sinks import warn_if_exposed

    caplog.set_level(logging.WARNING)
    assert warn_if_exposed(bind, 9090, 9876) is warned
    text = caplog.text
    assert (f"--bind {bind}" in text) is warned
    if warned:
        assert "anyone who can reach this machine" in text
        assert "ssh -L 9090:127.0.0.1:9090 -L 9876:127.0.0.1:9876" in text
        where = "every network interface" if bind == "0.0.0.0" else f"interface of {bind}"
        assert where in text


def test_out_suffix_and_format_must_agree(tiny_world, tmp_path, capsys):
    r_zarr = tmp_path / "r.zarr"
    code, _, err = query_chair(tiny_world, "--out", r_zarr, "--format", "npz", capsys=capsys)
    assert code == 2 and "names a .zarr but --format is npz" in err
    code, _, err = query_chair(tiny_world, "--out", tmp_path / "R.NPZ", capsys=capsys)
    assert code == 0, err
    assert np.load(tmp_path / "R.NPZ")["masks"].shape[0] == 1


def test_result_npz_records_the_up_axis(tiny_world, tmp_path, capsys):
    """``--out RESULT.npz`` keeps its positions' up axis: ``--up`` when given, else the
    one the map records (a y-up map read through the portable NPZ), else none."""
    from quash_plugins.adapters import convert_map
    from quash_plugins.engine.results import is_results_npz

    r = tmp_path / "r.npz"
    code, _, err = query_chair(tiny_world, "--out", r, capsys=capsys)
    assert code == 0, err
    assert "up" not in np.load(r).files  # the map records none: +z is assumed
    code, _, err = query_chair(tiny_world, "--out", r, "--up=-y", capsys=capsys)
    assert code == 0, err
    assert str(np.load(r)["up"]) == "-y" and is_results_npz(r)
    # written with a space, as every other option is ('expected one argument' before)
    code, _, err = query_chair(tiny_world, "--out", r, "--up", "-x", capsys=capsys)
    assert code == 0, err
    assert str(np.load(r)["up"]) == "-x"
    y_up = convert_map(tiny_world["map"], tmp_path / "y.npz", up="+y")
    code, _, err = run_cli(
        "query", y_up, "chair", "-c", tiny_world["config"], "--out", r, capsys=capsys
    )
    assert code == 0, err
    assert str(np.load(r)["up"]) == "+y"
    assert json.loads(str(np.load(r)["provenance"]))["map"]["up"] == "+y"


@pytest.mark.parametrize("suffix", ["npz", "zarr"])
def test_results_record_the_up_axis_and_read_it_back(tiny_world, tmp_path, capsys, suffix):
    """A results NPZ and a results Zarr store record the up axis the same way (``--up``,
    else the map's, else none) and ``up_from_npz`` / ``up_from_zarr`` read it back."""
    if suffix == "zarr":
        pytest.importorskip("zarr")
        pytest.importorskip("dask")
    from quash_plugins.adapters import convert_map, up_from_npz, up_from_zarr

    read_up = up_from_npz if suffix == "npz" else up_from_zarr
    r = tmp_path / f"r.{suffix}"
    code, _, err = query_chair(tiny_world, "--out", r, capsys=capsys)
    assert code == 0, err
    assert read_up(r) is None  # the map records none: +z is assumed
    code, _, err = query_chair(tiny_world, "--out", r, "--up=-x", capsys=capsys)
    assert code == 0, err
    assert read_up(r) == "-x"
    y_up = convert_map(tiny_world["map"], tmp_path / f"y.{suffix}", up="+y")
    assert read_up(y_up) == "+y"  # the converted map itself
    code, _, err = run_cli(
        "query", y_up, "chair", "-c", tiny_world["config"], "--out", r, capsys=capsys
    )
    assert code == 0, err
    assert read_up(r) == "+y"
    code, _, err = run_cli(
        "query",
        y_up,
        "chair",
        "-c",
        tiny_world["config"],
        "--out",
        r,
        "--up",
        "+z",
        capsys=capsys,
    )
    assert code == 0, err
    assert read_up(r) == "+z"  # --up overrides the map's


def test_an_adapter_without_options_refuses_one_by_name(tiny_world, capsys):
    code, _, err = query_chair(tiny_world, "-o", "nosuch=1", capsys=capsys)
    assert code == 1
    assert "Adapter 'npz' does not accept parameter 'nosuch'. Accepted: (none)." in err


def test_instances_read_off_when_the_config_groups_none(tiny_world, tmp_path, capsys):
    """A config with instances: false shows 'off' (table) and null (--json), not 0."""
    cfg = tmp_path / "off.yaml"
    cfg.write_text(tiny_world["config"].read_text() + "instances: false\n")
    (tmp_path / tiny_world["table"].name).write_bytes(tiny_world["table"].read_bytes())
    code, out, err = query_chair(tiny_world, "--json", capsys=capsys, config=cfg)
    assert code == 0, err
    assert json.loads(out)["results"][0]["instances"] is None
    code, out, err = query_chair(tiny_world, "--json", capsys=capsys)
    assert isinstance(json.loads(out)["results"][0]["instances"], int)


def test_each_commands_rerun_options_say_what_it_logs(capsys):
    """Each command's Rerun group says what it logs: quash eval the map, each config's
    results coloured by outcome, and its metrics."""
    said = {}
    for name in ("query", "eval", "demo"):
        with pytest.raises(SystemExit):
            main([name, "--help"])
        said[name] = " ".join(capsys.readouterr().out.split())
    assert "Log the map and every query to Rerun" in said["query"]
    assert "Log the evaluation to Rerun" in said["eval"]
    assert "the map, each config's results" in said["eval"]
    assert "coloured by outcome against the ground truth" in said["eval"]
    assert "Log the scene, every method's query results and the evaluation" in said["demo"]


def test_rerun_options_paragraph_is_wrapped_like_the_rest_of_the_help(capsys):
    """The group's paragraph (eval's was one 214-character line) is wrapped like the
    descriptions, to the terminal's width (80 here, at most 88 anywhere it is checked)."""
    for name in ("query", "eval", "demo"):
        with pytest.raises(SystemExit):
            main([name, "--help"])
        out = capsys.readouterr().out
        start = out.index("Rerun viewer:")
        section = out[start : out.index("--rrd FILE.rrd", start)]
        assert "Log the " in section
        assert max(len(line) for line in section.splitlines()) <= 88, section


def test_query_out_npz_records_where_items_are_and_how_it_was_made(tiny_world, tmp_path, capsys):
    """The results file alone can be plotted (the map's positions, row for row) and says
    how it was made: version, map, config, encoder fingerprint, each query's set and
    decision; a second run may replace it without --force (it is a previous output)."""
    from quash_plugins import Quash, __version__
    from quash_plugins.engine.results import is_results_npz

    out = tmp_path / "r.npz"
    args = ("query", tiny_world["map"], "chair", "sofa", "-c", tiny_world["config"])
    code, _, err = run_cli(*args, "--out", out, capsys=capsys)
    assert code == 0, err
    with np.load(out) as z:
        positions = np.load(tiny_world["map"])["positions"]
        np.testing.assert_array_equal(z["positions"], positions)
        assert z["masks"].shape == (2, len(positions)) and "grid_index" not in z.files
        record = json.loads(str(z["provenance"]))
    q = Quash.from_config(str(tiny_world["config"]))
    assert record["quash_plugins"] == __version__
    assert record["map"]["path"] == str(tiny_world["map"])
    assert record["config"] == "vlmaps-contrast"
    assert record["config_file"] == str(tiny_world["config"])
    assert record["encoder"] == {"name": "table", "fingerprint": q.encoder.fingerprint()}
    chair = record["queries"][0]
    assert chair["query"] == "chair" and chair["positives"] == ["chair"]
    assert chair["negatives"] == ["other", "background", "nothing"]
    assert is_results_npz(out)
    code, _, err = run_cli(*args, "--out", out, capsys=capsys)
    assert code == 0, err


def test_query_out_npz_records_the_label_list_each_query_was_answered_from(
    tiny_world, tmp_path, capsys
):
    """A label-list method's results file says which list it was given (the map's label
    names, with the taxonomy beside the map) and which label each query resolved to, as
    quash eval's `given` column does: a held-out map's list, not the shipped one."""
    (tiny_world["dir"] / "map.taxonomy.yaml").write_text("chair: [armchair]\nsofa: []\n")
    cfg = tmp_path / "labels.yaml"
    cfg.write_text(
        f"encoder: {{name: table, file: {tiny_world['table']}}}\n"
        "heuristic: {name: label-list}\nclassifier: label-argmax\n"
    )
    out = tmp_path / "r.npz"
    code, _, err = run_cli(
        "query", tiny_world["map"], "armchair", "-c", cfg, "--out", out, capsys=capsys
    )
    assert code == 0, err
    with np.load(out) as z:
        (armchair,) = json.loads(str(z["provenance"]))["queries"]
    assert armchair["label"] == "chair"
    assert armchair["labels_from"].endswith("map.taxonomy.yaml")
    assert armchair["resolved"]["to"] == "chair"


def test_query_and_eval_take_adapter_options(tmp_path, capsys):
    """-o KEY=VALUE reaches the adapter, as in quash convert: the cell size of a
    mobile-base VLMaps map (not stored in its file) scales the positions of the result;
    an option the adapter does not take is refused naming it."""
    pytest.importorskip("h5py")
    from quash_plugins.adapters._vlmaps import VLMapsAdapter

    path = VLMapsAdapter().write_example(tmp_path)
    table = tmp_path / "t.npz"
    rng = np.random.default_rng(0)
    words = ["chair", "other", "background", "nothing"]
    np.savez(table, texts=np.asarray(words), embeddings=rng.normal(size=(len(words), 8)))
    cfg = tmp_path / "c.yaml"
    cfg.write_text(
        f"encoder: {{name: table, file: {table}}}\nheuristic: none\nclassifier: contrast\n"
    )
    positions = {}
    for cs in ("0.05", "0.1"):
        out = tmp_path / f"r{cs}.npz"
        code, _, err = run_cli(
            "query", path, "chair", "-c", cfg, "-o", f"cs={cs}", "--out", out, capsys=capsys
        )
        assert code == 0, err
        positions[cs] = np.load(out)["positions"]
    np.testing.assert_allclose(positions["0.1"], 2 * positions["0.05"], rtol=1e-5, atol=1e-6)
    code, _, err = run_cli("query", path, "chair", "-c", cfg, "-o", "cz=0.1", capsys=capsys)
    assert code != 0 and "'cz'" in err and "cs" in err
    code, _, err = run_cli("query", path, "chair", "-c", cfg, "-o", "cs", capsys=capsys)
    assert code == 2 and "--option expects KEY=VALUE" in err
    code, _, err = run_cli(
        "eval", path, "-c", cfg, "-o", "cz=0.1", "--queries", "chair=chair", capsys=capsys
    )
    assert code != 0 and "'cz'" in err


def test_query_out_with_an_unknown_suffix_is_refused_before_any_work(tiny_world, tmp_path, capsys):
    """--out out.h5df wrote an NPZ under a VLMaps-looking name: refused, the fix named."""
    for name in ("out.h5df", "out"):
        code, _, err = query_chair(tiny_world, "--out", tmp_path / name, capsys=capsys)
        assert code == 2 and "RESULT.npz" in err and "--format" in err
        assert not (tmp_path / name).exists()
    code, _, err = query_chair(
        tiny_world, "--out", tmp_path / "out.h5df", "--format", "npz", capsys=capsys
    )
    assert code == 0, err
    assert np.load(tmp_path / "out.h5df")["masks"].shape[0] == 1


def test_make_scene_passes_encoder_options(tmp_path, capsys, monkeypatch):
    """--encoder-option KEY=VALUE reaches the encoder (a plugin's dim, a batch size); an
    option the encoder does not take is a usage error naming it and the accepted ones."""
    import quash_plugins.demo.scene as scene

    seen = {}

    def stop(encoder, opts, cache=None):
        seen["batch_size"] = encoder.batch_size
        raise KeyboardInterrupt

    monkeypatch.setattr(scene, "make_scene", stop)
    out = tmp_path / "s.npz"
    code, _, _ = run_cli(
        "make-scene",
        out,
        "--encoder",
        "minilm",
        "--encoder-option",
        "batch_size=16",
        capsys=capsys,
    )
    assert code == 130 and seen == {"batch_size": 16}
    code, _, err = run_cli(
        "make-scene", out, "--encoder", "minilm", "--encoder-option", "bogus=1", capsys=capsys
    )
    assert code == 2 and "'bogus'" in err and "batch_size" in err
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, bad, usage, hint",
    [
        (["query", "m.npz", "chair", "--formt", "npz"], "--formt npz", "quash query", "--format"),
        (["eval", "m.npz", "--queris", "bed"], "--queris bed", "quash eval", "--queries"),
        (["query", "m.npz", "--bogus", "chair"], "--bogus", "quash query", None),
        (["--bogus"], "--bogus", "quash", None),
    ],
)
def test_an_unknown_option_shows_its_subcommands_usage_and_the_nearest_option(
    argv, bad, usage, hint, capsys
):
    """argparse gave the top-level usage ('quash [-h] ... COMMAND ...') for a subcommand's
    unknown option, which lists none of the options the user could have meant."""
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith(f"usage: {usage} [")
    assert f"{usage}: error: unrecognized arguments: {bad}" in err
    assert f"'{usage} --help' lists the options" in err
    assert (f"did you mean {hint}?" in err) if hint else ("did you mean" not in err)


def test_expand_prints_number_lists_on_a_line_within_the_width():
    """`quash expand --map` shows negative_groups (one size per label) as a flow list that
    fits the terminal, not one line per label; the YAML still reads back the same."""
    import yaml

    from quash_plugins.cli.cmd_expand import _provenance_yaml
    from quash_plugins.core.types import QuerySet

    groups = [6] * 34 + [5, 5, 5, 4, 5]
    prov = {"label": "office chair", "negative_groups": groups, "used": {"labels": ["a", "b"]}}
    qs = QuerySet("chair", ["chair"], ["floor"], provenance=prov)
    text = _provenance_yaml(qs, width=78)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 78
    assert sum("6, 6" in line for line in lines) >= 1 and len(lines) < 12
    assert "- a" in text  # a list of names stays a block list
    assert yaml.safe_load("\n".join(line[2:] for line in lines)) == qs.to_dict()["provenance"]


def test_demo_help_counts_what_the_demo_runs():
    """``quash demo --help`` listed fewer methods than the demo runs."""
    from quash_plugins.cli import cmd_demo
    from quash_plugins.demo.runner import DEMO_ABSENT, DEMO_CONFIGS, DEMO_QUERIES

    words = dict(
        enumerate(
            ["zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten"]
        )
    )
    words.update({11: "eleven", 12: "twelve"})
    text = " ".join(cmd_demo.DESCRIPTION.split())
    assert f"runs {words[len(DEMO_CONFIGS)]} methods" in text
    assert f"on {words[len(DEMO_QUERIES)]} queries" in text
    assert f"{words[len(DEMO_ABSENT)]} absence queries" in text
    for kind in ("VLMaps", "ConceptFusion", "LERF", "OpenScene", "vocabulary", "adjectives"):
        assert kind in text


def test_negative_up_axes_are_joined_to_up_and_nothing_else_is():
    from quash_plugins.cli.main import _join_negative_axes

    assert _join_negative_axes(["query", "m", "q", "--up", "-y"]) == ["query", "m", "q", "--up=-y"]
    assert _join_negative_axes(["--up", "+y", "-v"]) == ["--up", "+y", "-v"]
    assert _join_negative_axes(["--up", "-v"]) == ["--up", "-v"]  # no axis: argparse says
    assert _join_negative_axes(["q", "--", "--up", "-z"]) == ["q", "--", "--up", "-z"]


@pytest.mark.parametrize("suffix", ["npz", "zarr"])
def test_a_result_given_as_the_map_is_named_a_result_with_its_map(
    tiny_world, tmp_path, capsys, suffix
):
    """``quash query r.npz ...`` on what ``quash query --out`` wrote said only "missing
    array 'embeddings'": it now says the file is a query result and names the map the
    result was made from (its provenance)."""
    if suffix == "zarr":
        pytest.importorskip("zarr")
        pytest.importorskip("dask")
    r = tmp_path / f"r.{suffix}"
    code, _, err = query_chair(tiny_world, "--out", r, capsys=capsys)
    assert code == 0, err
    code, _, err = run_cli("query", r, "chair", "-c", tiny_world["config"], capsys=capsys)
    assert code == 1
    assert "is a query result" in err and str(Path(tiny_world["map"]).resolve()) in err


@pytest.mark.parametrize("kind", ["encoder", "Encoders", "encoders"])
def test_plugins_kind_takes_the_singular_a_config_section_uses(kind, capsys):
    code, out, _ = run_cli("plugins", "--kind", kind, "--json", capsys=capsys)
    assert code == 0
    rows = json.loads(out)
    assert rows and {r["kind"] for r in rows} == {"encoders"}


def test_plugins_kind_choices_are_the_registrys_kinds():
    """The choices are written out so that building the parser imports no registry."""
    from quash_plugins.cli import cmd_plugins
    from quash_plugins.core import registry

    assert cmd_plugins.KINDS == registry.KINDS


def test_plugins_kind_still_refuses_an_unknown_kind(capsys):
    with pytest.raises(SystemExit) as stop:
        run_cli("plugins", "--kind", "mapper", capsys=capsys)
    assert stop.value.code == 2
    assert "invalid choice: 'mapper'" in capsys.readouterr().err


def test_no_help_example_runs_a_continued_line_into_one():
    """A '\\' at the end of an EPILOG line in a plain string joined the next line onto it
    (quash bench --help showed '--tables sources       --llm-model ...' as one line):
    every example that continues a command ends its line with the backslash it shows."""
    from quash_plugins.cli.main import _commands

    for mod in _commands():
        for line in (getattr(mod, "EPILOG", "") or "").splitlines():
            assert not re.search(r"\S {3,}--?\w", line), (mod.NAME, line)
