"""quash demo end to end on the tiny scene with the shipped configs (real MiniLM).

The demo runs once per module (it builds the scene and loads MiniLM); the tests read
what it wrote. Expected values are computed from the shipped configs and the scene, never
copied from an earlier run.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import pytest
import yaml

from quash_plugins.adapters import read_map
from quash_plugins.cli.main import main
from quash_plugins.core.config import QuashConfig
from quash_plugins.demo.runner import cache_root, demo_config_paths
from quash_plugins.evaluation.report import evaluate


def test_demo_configs_ship_as_package_data():
    paths = demo_config_paths()
    assert len(paths) >= 5 and all(p.exists() for p in paths)


def test_demo_list_configs_prints_the_shipped_paths_and_runs_nothing(tmp_path, capsys):
    out = tmp_path / "never"
    assert main(["demo", "--list-configs", "--out", str(out)]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed == [str(p) for p in demo_config_paths()]
    for line in printed:  # each line is a config a user can copy and run
        cfg = QuashConfig.from_yaml(line)
        assert cfg.name and cfg.encoder.name
    assert not out.exists() and not cache_root().exists()


def test_demo_list_configs_prints_long_paths_whole(monkeypatch, capsys):
    """An install path longer than a terminal line is printed on one line, as it is."""
    import quash_plugins.demo.runner as runner

    long = [f"/{'deep/' * 30}[v1]/demo-{i}.yaml" for i in range(2)]
    monkeypatch.setattr(runner, "demo_config_paths", lambda: [Path(p) for p in long])
    assert main(["demo", "--list-configs"]) == 0
    assert capsys.readouterr().out.splitlines() == long


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """``quash demo --tiny`` once, with its own cache folder (never the user's), as on a
    machine without VLMaps."""
    from _no_vlmaps import hide_vlmaps

    out = tmp_path_factory.mktemp("demo")
    cache = tmp_path_factory.mktemp("demo-cache")
    stdout, stderr = io.StringIO(), io.StringIO()
    with (
        pytest.MonkeyPatch.context() as mp,
        contextlib.redirect_stdout(stdout),
        contextlib.redirect_stderr(stderr),
    ):
        mp.setenv("QUASH_CACHE_DIR", str(cache))
        hide_vlmaps(mp)
        code = main(["demo", "--tiny", "--out", str(out)])
        scenes = sorted(cache_root().glob("scene-v*-tiny-seed0-*.npz"))
    return {
        "code": code,
        "out": out,
        "stdout": stdout.getvalue(),
        "stderr": stderr.getvalue(),
        "scenes": scenes,
        "json": json.loads((out / "demo.json").read_text()) if code == 0 else None,
    }


def _is_quash(name: str) -> bool:
    return name.startswith("quash")


def _summary_rows(markdown: str) -> list[str]:
    """Method names of the first table of a report, in order."""
    lines = markdown.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| method |"))
    names = []
    for line in lines[start + 2 :]:
        if not line.startswith("| "):
            break
        names.append(line.split("|")[1].strip())
    return names


@pytest.mark.slow
def test_demo_tiny_end_to_end(demo):
    assert demo["code"] == 0, demo["stdout"]
    out = demo["out"]
    for name in ("demo.md", "demo.json", "demo.png", "demo.rrd"):
        assert (out / name).stat().st_size > 0, name
    # the scene is cached under $QUASH_CACHE_DIR/demo
    assert len(demo["scenes"]) == 1
    # the console shows rich tables; the Markdown is only in demo.md
    assert "|---" not in demo["stdout"] and "|---" in (out / "demo.md").read_text()


#: The outcome colours of ``quash eval --rrd``, spelled here rather than read from the
#: package: true positives blue, false positives vermillion, false negatives yellow.
BLUE, VERMILLION, YELLOW = (0, 114, 178), (213, 94, 0), (240, 228, 66)


def _outcome_counts(rrd: Path) -> tuple[dict[tuple[str, int], dict], dict[tuple[str, int], str]]:
    """``{(matches entity, step): {colour: items drawn in it}}`` and ``{(config entity,
    step): query document}`` of a recording."""
    from rerun.chunk import RrdReader

    colours: dict[tuple[str, int], dict] = {}
    docs: dict[tuple[str, int], str] = {}
    for chunk in RrdReader(rrd).stream().to_chunks():
        entity = chunk.entity_path.lstrip("/")
        rb = chunk.to_record_batch()
        if "query" not in rb.schema.names:
            continue
        steps = rb.column("query").to_pylist()
        if entity.startswith("queries/") and "TextDocument:text" in rb.schema.names:
            for t, v in zip(steps, rb.column("TextDocument:text").to_pylist()):
                docs[entity.removeprefix("queries/"), t] = str(v[0])
        if not entity.startswith("world/matches/"):
            continue
        kind = "Boxes3D" if "Boxes3D:centers" in rb.schema.names else "Points3D"
        centers = rb.column(f"{kind}:{'centers' if kind == 'Boxes3D' else 'positions'}")
        packed = rb.column(f"{kind}:colors").to_pylist()
        for t, c, p in zip(steps, centers.to_pylist(), packed):
            p = (p or []) * (len(c or []) if len(p or []) == 1 else 1)
            drawn: dict[tuple, int] = {}
            for x in p:
                rgb = ((x >> 24) & 255, (x >> 16) & 255, (x >> 8) & 255)
                drawn[rgb] = drawn.get(rgb, 0) + 1
            colours[entity.removeprefix("world/matches/"), t] = drawn
    return colours, docs


@pytest.mark.slow
def test_demo_recording_colours_each_result_by_outcome(demo):
    """demo.rrd coloured every method's matches magenta while ``quash eval --rrd`` coloured
    them by outcome: each method's drawn items at each step are now exactly its TP in blue,
    FP in vermillion and FN in yellow, as demo.json counts them (the scene has no
    unlabelled item, so nothing is magenta), and each query's document names the colours."""
    from quash_plugins.viewer import MATCH_COLOR, slugify

    assert demo["code"] == 0, demo["stderr"]
    colours, docs = _outcome_counts(demo["out"] / "demo.rrd")
    assert colours, "no matches in demo.rrd"
    magenta = [k for k, drawn in colours.items() if tuple(MATCH_COLOR) in drawn]
    assert not magenta, f"matches drawn magenta, not by outcome: {magenta[:5]}"
    for c in demo["json"]["configs"]:
        slug = slugify(c["name"], "config")
        absent = c["absence"]["per_query"]
        texts = [*c["per_query"], *absent]
        for step, q in enumerate(texts):
            m = c["per_query"].get(q)
            want = (m["tp"], m["fp"], m["fn"]) if m else (0, absent[q]["matched"], 0)
            drawn = colours.get((slug, step), {})
            got = tuple(drawn.get(rgb, 0) for rgb in (BLUE, VERMILLION, YELLOW))
            assert got == want and sum(drawn.values()) == sum(want), (c["name"], q, drawn)
            doc = docs[slug, step]
            assert f"**blue**: true positives (matched, of the label) {want[0]:,}" in doc
            assert f"**vermillion**: false positives (matched, not of the label) {want[1]:,}" in doc
            assert f"**yellow**: false negatives (of the label, not matched) {want[2]:,}" in doc


def _announced(text: str) -> list[str]:
    """The paths of every ``wrote A, B in 1.2 s`` / ``wrote A`` line of ``text``."""
    paths = []
    for line in text.splitlines():
        if line.startswith("wrote "):
            paths += line.removeprefix("wrote ").rsplit(" in ", 1)[0].split(", ")
    return paths


@pytest.mark.slow
def test_demo_announces_each_output_once(tmp_path, monkeypatch, capsys):
    """Each file written is named once, the recording where --rrd put it: demo.rrd in
    --out was named twice (the recording's own line, then the demo's list), and an
    earlier list named demo.rrd where --rrd had written another file."""
    monkeypatch.setenv("COLUMNS", "1000")  # one line, no path folded
    out = tmp_path / "out"
    assert main(["demo", "--tiny", "--out", str(out), "--rrd", str(out / "mine.rrd")]) == 0
    said = capsys.readouterr()
    announced = _announced(said.out) + _announced(said.err)
    expected = [str(out / n) for n in ("demo.md", "demo.json", "demo.png", "mine.rrd")]
    assert sorted(announced) == sorted(expected), said
    assert all(Path(w).is_file() for w in announced)


@pytest.mark.slow
def test_demo_quiet_says_only_warnings_and_errors(tmp_path, monkeypatch, capsys):
    """--quiet: no "wrote ..." line (the demo's and its recording's were printed all the
    same), no progress or INFO line; the comparison is still printed, and every file
    is written."""
    monkeypatch.setenv("COLUMNS", "1000")
    out = tmp_path / "out"
    assert main(["-q", "demo", "--tiny", "--out", str(out)]) == 0
    said = capsys.readouterr()
    assert not _announced(said.out) and not _announced(said.err), said
    assert not [ln for ln in said.err.splitlines() if ln.startswith("INFO")], said.err
    assert "quash demo: " in said.out
    for name in ("demo.md", "demo.json", "demo.png", "demo.rrd"):
        assert (out / name).is_file(), name


@pytest.mark.slow
def test_demo_without_vlmaps_says_its_templates_at_info_and_in_the_json(demo):
    """The VLMaps peers' stand-in templates are expected on a machine without VLMaps: said
    at INFO, never as a warning, and demo.json says which list each method used."""
    assert demo["code"] == 0, demo["stderr"]
    said = [ln for ln in demo["stderr"].splitlines() if "VLMaps" in ln]
    assert said and all(ln.startswith("INFO") for ln in said), demo["stderr"]
    rows = {c["name"]: c for c in demo["json"]["provenance"]["configs"]}
    for name in ("vlmaps", "vlmaps-labels"):
        assert "default list (vlmaps-or-default: no VLMaps installed)" in rows[name]["templates"]


@pytest.mark.slow
def test_demo_table_order_follows_the_shipped_configs(demo):
    """One row per shipped config, in the order of demo_config_paths(); the peers' rules
    first, then QuASH, in the JSON, demo.md and what the command printed."""
    assert demo["code"] == 0, demo["stdout"]
    expected = [yaml.safe_load(p.read_text())["name"] for p in demo_config_paths()]
    names = [c["name"] for c in demo["json"]["configs"]]
    assert names == expected
    assert _summary_rows((demo["out"] / "demo.md").read_text()) == expected
    # The printed summary table: one row per method, "name  0.123 ...", in that order.
    rows = [re.search(rf"^\s*{re.escape(n)}\s+\d", demo["stdout"], re.M) for n in expected]
    assert all(rows), demo["stdout"]
    assert [m.start() for m in rows] == sorted(m.start() for m in rows)
    kinds = [_is_quash(n) for n in names]
    assert any(kinds) and not all(kinds), "the demo compares peers with QuASH"
    assert kinds == sorted(kinds), f"peers first, then QuASH: {names}"


@pytest.mark.slow
def test_quash_beats_the_fair_peer(demo):
    """QuASH's F1 (the demo's first QuASH row) against OpenScene's/VLMaps' label argmax
    given the same information, the scene's label list, scored by the same evaluate()
    on the same scene, queries and absence queries."""
    assert demo["code"] == 0, demo["stdout"]
    report = demo["json"]
    quash = next(c for c in report["configs"] if _is_quash(c["name"]))
    scene = demo["scenes"][0]
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("QUASH_CACHE_DIR", str(scene.parent.parent))
        lmap = read_map(scene, adapter="npz")
        peer = {
            "name": "label-argmax (scene labels)",
            "encoder": "minilm",
            "heuristic": "none",
            "negatives": list(lmap.label_names),
            "classifier": "label-argmax",
            "instances": False,
        }
        queries = list(quash["per_query"])
        absent = list(quash["absence"]["per_query"])
        fair = evaluate(lmap, [peer], queries=queries, absent=absent).configs[0]
    assert list(fair["per_query"]) == queries
    assert quash["mean"]["f1"] > fair["mean"]["f1"], (quash["mean"], fair["mean"])
    # and it keeps the promise the peer breaks: nothing for the absent objects
    assert quash["absence"]["score"] == 1.0, quash["absence"]


def _table_rows(text: str, header: str) -> dict[str, list[str]]:
    """``{first cell: cells}`` of the table under the line starting with ``header``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header))
    rows = {}
    for line in lines[start + 2 :]:
        if not line.startswith("| "):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        rows[cells[0]] = cells
    return rows


@pytest.mark.slow
def test_the_docs_demo_tables_are_what_the_full_demo_prints(tmp_path, monkeypatch):
    """docs/evaluation.md shows the full demo's output, and README.md its figures: both
    must be what `quash demo` prints today (the evaluation block once fell behind)."""
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "cache"))
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["demo", "--out", str(tmp_path / "out"), "--no-rrd", "-q"]) == 0
    demo = (tmp_path / "out" / "demo.md").read_text(encoding="utf-8")
    root = Path(__file__).resolve().parents[2]
    doc = (root / "docs" / "evaluation.md").read_text(encoding="utf-8")
    block = doc[doc.index("# quash demo: 10 queries") :]
    block = block[: block.index("```")]
    for header in ("| method |", "| query |", "| absence query |"):
        shown, ran = _table_rows(block, header), _table_rows(demo, header)
        assert shown.keys() == ran.keys(), header
        for name, cells in shown.items():
            differ = [
                (column, a, b)
                for column, (a, b) in enumerate(zip(cells, ran[name], strict=True))
                if not _close(a, b)
            ]
            assert not differ, (header, name, "(column, docs, demo):", differ)
    # README: F1, recall, AP, absence and present -> empty of each method's row
    ran = _table_rows(demo, "| method |")
    readme = (root / "README.md").read_text(encoding="utf-8")
    names = {
        "VLMaps (its": "vlmaps",
        "ConceptFusion": "conceptfusion",
        "LERF": "lerf",
        "VLMaps with its": "vlmaps-labels",
        "OpenScene's": "openscene-labels",
        "**QuASH**": "quash-labels",
        "QuASH as in the paper": "quash-taxonomy-svm",
    }
    shown = _table_rows(readme, "| method | given | F1 | recall | AP |")
    assert len(shown) == len(names)
    for first, cells in shown.items():
        name = next(
            v for k, v in sorted(names.items(), key=lambda kv: -len(kv[0])) if first.startswith(k)
        )
        want = [ran[name][i] for i in (2, 4, 6, 8, 9)]  # F1, recall, AP, absence, present -> empty
        assert all(_close(a, b) for a, b in zip(cells[2:], want, strict=True)), (name, cells, want)


def _close(shown: str, ran: str) -> bool:
    """A cell of the docs against the same cell of the demo's output. Scores agree to
    0.005 and counts to 1 %: MiniLM's embeddings differ by ~1e-8 with the batch they were
    encoded in (a scene built with a warm text cache, or on another CPU), which moves a
    near-tied item or two (the vocabulary's tv: F1 0.958-0.968 between builds); every
    other cell is compared as written."""
    a, b = shown.strip("*"), ran.strip("*")
    try:
        x, y = float(a), float(b)
    except ValueError:
        return a == b
    if "." in a or "." in b:
        return abs(x - y) <= 0.005 + 1e-9  # 0.963 - 0.958 is 0.0050000000000000044 in floats
    return abs(x - y) <= max(1.0, 0.01 * abs(y))


def test_a_cached_scene_of_another_embedding_function_is_built_again(tmp_path, monkeypatch):
    """The demo's cached scene is named by the encoder's name; one that other weights
    under that name built is not reused (it would be queried in another space), one
    that these weights built, now or under an earlier name, is."""
    import numpy as np

    import quash_plugins.demo.runner as runner

    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path))
    built = []
    monkeypatch.setattr(runner, "make_scene", lambda enc, opts, cache=None: "scene")
    monkeypatch.setattr(runner, "write_scene", lambda scene, path, opts: built.append(path))

    class Enc:
        name = "minilm"

        def fingerprint(self):
            return "sentence-transformers-new"

        def earlier_fingerprints(self):
            return ["sentence-transformers-old"]

    path = tmp_path / "demo" / f"scene-v{runner.SCENE_VERSION}-tiny-seed0-minilm.npz"
    path.parent.mkdir(parents=True)
    for recorded, rebuilt in (
        ("sentence-transformers-new", False),
        ("sentence-transformers-old", False),
        ("sentence-transformers-other", True),
    ):
        np.savez(path, embeddings=np.zeros((1, 2)), encoder_fingerprint=recorded)
        built.clear()
        assert runner.demo_scene(Enc(), tiny=True) == path
        assert built == ([path] if rebuilt else []), recorded


def test_the_demo_says_how_far_it_is_method_by_method(tmp_path, monkeypatch, caplog):
    """Without a terminal the full demo said nothing between reading the scene and its
    table (a minute and more on 2 cores): each method's pass is now a progress step."""
    import logging

    import quash_plugins.core.progress as progress_mod
    from quash_plugins.demo.runner import run_demo

    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(progress_mod, "MIN_INTERVAL", 0.0)  # every step is news
    monkeypatch.setattr(progress_mod, "QUIET", False)  # as a program's, not after quash -q
    package = logging.getLogger("quash_plugins")  # propagating to caplog, as a program's
    monkeypatch.setattr(package, "handlers", [])
    monkeypatch.setattr(package, "propagate", True)
    monkeypatch.setattr(progress_mod.sys.stderr, "isatty", lambda: False, raising=False)
    caplog.set_level(logging.INFO, logger="quash_plugins.progress")
    configs = demo_config_paths()[:2]
    report, _ = run_demo(tiny=True, configs=configs)
    lines = [r.getMessage() for r in caplog.records if r.name == "quash_plugins.progress"]
    steps = [ln for ln in lines if ln.startswith(f"evaluating {len(configs)} methods: ")]
    assert [s.split(": ")[1].split(" ")[0] for s in steps] == ["1/2", "2/2"], lines
    assert len(report.configs) == len(configs)


@pytest.mark.slow
def test_demo_prints_its_paths_as_they_are(tmp_path, monkeypatch, capsys):
    """The scene's path and --out were printed as rich markup: a '[v1]' folder vanished
    from both ('/tmp/c/demo/...'), so the printed path named no file."""
    monkeypatch.setenv("COLUMNS", "1000")  # one line each, no path folded
    monkeypatch.setenv("QUASH_CACHE_DIR", str(tmp_path / "cache[v1]"))
    out = tmp_path / "out[v1]"
    assert main(["demo", "--tiny", "--no-rrd", "--out", str(out)]) == 0
    said = capsys.readouterr()
    lines = said.out.splitlines()
    [scene] = sorted(cache_root().glob("scene-v*-tiny-seed0-*.npz"))
    assert f"scene: {scene}" in lines
    [wrote] = [ln for ln in said.err.splitlines() if ln.startswith("wrote ")]
    written = wrote.removeprefix("wrote ").rsplit(" in ", 1)[0].split(", ")
    assert written == [str(out / n) for n in ("demo.md", "demo.json", "demo.png")]
    assert all(Path(w).is_file() for w in written)
