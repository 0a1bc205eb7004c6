"""quash bench (run_bench, bench_configs) on a tiny generated scene, fast and offline.

The scene and every text are embedded by the conformance kit's hashing encoder,
registered for this module, so every word of every ablation has an embedding.
"""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest
from _bench import hashing_scene

from quash_plugins.cli.main import main
from quash_plugins.core.config import QuashConfig
from quash_plugins.core.text import ZERO_TOKEN
from quash_plugins.engine.pipeline import Quash
from quash_plugins.evaluation.ablations import (
    ANTONYMS,
    CLASSIFIERS,
    SOURCES,
    TABLES,
    bench_configs,
    run_bench,
)
from quash_plugins.evaluation.metrics import macro_mean, query_metrics, valid_items
from quash_plugins.evaluation.report import DEFAULT_EXCLUDE

ENCODER = "hashing-bench"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    yield from hashing_scene(tmp_path_factory, ENCODER)


def _names(cfgs):
    return [c["name"] for c in cfgs]


def test_bench_configs_cover_every_table_and_parse():
    tax = "scene.taxonomy.yaml"
    full = bench_configs(tax, ENCODER, llm={"model": "m"})
    assert list(full) == list(TABLES)
    # antonyms: one contrast row per antonym word, the zero vector without templates
    rows = full["antonyms"]
    assert [c["negatives"] for c in rows] == [[a] for a in ANTONYMS]
    assert all(c["classifier"] == "contrast" and c["heuristic"] == "none" for c in rows)
    assert [("prompt_templates" in c) for c in rows] == [a != ZERO_TOKEN for a in ANTONYMS]
    # sources: the full synonym x antonym grid; llm reads its cache only
    assert _names(full["sources"]) == [f"{s} x {a}" for s in SOURCES for a in SOURCES]
    llm = [c for c in full["sources"] if c["name"] == "llm x llm"][0]["heuristic"]
    assert llm["synonyms"] == {"name": "llm", "offline": True, "model": "m"}
    # classifiers: every ablated classifier on the taxonomy sets, then the refinements
    cls = full["classifiers"]
    assert [c["classifier"] for c in cls[: len(CLASSIFIERS)]] == list(CLASSIFIERS.values())
    assert [c["refine"]["classifier"] for c in cls[len(CLASSIFIERS) :]] == [
        "svm-rbf",
        "nearest-sample",
    ]
    assert all(c["heuristic"]["file"] == tax for c in cls)
    for table, cfgs in full.items():
        assert len(set(_names(cfgs))) == len(cfgs), f"duplicate names in {table}"
        for c in cfgs:
            parsed = QuashConfig.from_dict(c)  # an unknown key would raise ConfigError
            assert parsed.name == c["name"]
    # without a taxonomy or an llm: no taxonomy rows, no classifier table, a 2 x 2 grid
    bare = bench_configs(None, ENCODER)
    assert "classifiers" not in bare and len(bare["prompt"]) == 2
    offline = [s for s in SOURCES if s not in ("taxonomy", "llm")]
    assert _names(bare["sources"]) == [f"{s} x {a}" for s in offline for a in offline]


def test_quash_bench_cli_writes_the_tables_it_was_asked_for(scene, tmp_path, capsys):
    out = tmp_path / "bench"
    code = main(
        [
            "bench",
            str(scene / "scene.npz"),
            "--encoder",
            ENCODER,
            "--tables",
            "antonyms,classifiers",
            "--no-cache",
            "--out",
            str(out),
        ]
    )
    assert code == 0, capsys.readouterr().err
    printed, status = capsys.readouterr()
    data = json.loads((out / "bench.json").read_text())
    assert list(data) == ["antonyms"]  # classifiers need --taxonomy
    md = (out / "bench.md").read_text()
    assert "## Classifiers\n\n_skipped: needs --taxonomy_" in md
    # the table on stdout, the progress line on stderr (status never mixes with results)
    assert "table antonyms: done" in status and "table antonyms: done" not in printed
    assert "\nAntonyms (baseline)\n" in printed
    # --quiet: the tables, without the progress lines between them
    args = ["bench", str(scene / "scene.npz"), "--encoder", ENCODER, "--tables", "antonyms"]
    assert main([*args, "--no-cache", "--out", str(out), "-q"]) == 0
    quiet, quiet_status = capsys.readouterr()
    assert "table antonyms: done" not in quiet + quiet_status
    assert "\nAntonyms (baseline)\n" in quiet
    assert "|---" not in printed  # rich tables on the console; the Markdown is in bench.md
    # a plot is named on the console, not linked as Markdown; bench.md keeps the link
    assert "![" not in printed and "](antonyms.png)" not in printed
    assert f"plot: {out / 'antonyms.png'}" in printed
    assert "![Antonyms (baseline)](antonyms.png)" in md
    assert (out / "antonyms.png").read_bytes()[:4] == b"\x89PNG"
    assert not (out / "classifiers.png").exists()
    rows = data["antonyms"]["configs"]
    cfgs = {c["name"]: c for c in bench_configs(None, ENCODER)["antonyms"]}
    assert sorted(_names(rows)) == sorted(cfgs)
    f1 = [r["mean"]["f1"] for r in rows]
    assert f1 == sorted(f1, reverse=True), "rows are ranked by F1"
    # one row recomputed independently: its config's masks, scored query by query
    row = next(r for r in rows if r["name"] == "baseline other")
    quash = Quash.from_config({**cfgs["baseline other"], "cache": False})
    lmap = quash.read_map(scene / "scene.npz")
    names = list(lmap.label_names)
    present = [names[i] for i in np.unique(lmap.labels) if names[i] not in DEFAULT_EXCLUDE]
    assert sorted(row["per_query"]) == sorted(present)
    valid = valid_items(lmap.labels, names, exclude=DEFAULT_EXCLUDE)
    results = quash.query_many(lmap, present)
    per = {
        q: query_metrics(r.mask, lmap.labels == names.index(q), valid)
        for q, r in zip(present, results)
    }
    for q in present:
        assert row["per_query"][q]["f1"] == pytest.approx(per[q]["f1"])
    assert row["mean"]["f1"] == pytest.approx(macro_mean(per)["f1"])
    assert "| baseline other | " in md


def test_run_bench_with_a_taxonomy_queries_and_absence(scene, tmp_path):
    done = []
    results = run_bench(
        scene / "scene.npz",
        str(scene / "scene.taxonomy.yaml"),
        tmp_path / "b",
        tables=("classifiers",),
        encoder=ENCODER,
        overrides={"cache": False},
        queries=["wall", "floor", "chair"],
        absent=("piano",),
        on_table=done.append,
    )
    assert done == ["classifiers"] and list(results) == ["classifiers"]
    expected = _names(bench_configs(str(scene / "scene.taxonomy.yaml"), ENCODER)["classifiers"])
    rows = results["classifiers"]["configs"]
    assert sorted(_names(rows)) == sorted(expected) and not results["classifiers"]["notes"]
    for r in rows:
        assert set(r["per_query"]) == {"wall", "floor", "chair"}
        assert set(r["absence"]["per_query"]) == {"piano"}
    on_disk = json.loads((tmp_path / "b" / "bench.json").read_text())
    assert on_disk == json.loads(json.dumps(results))
    # what the table scored is recorded as quash eval --json records it (bench.json had
    # the scores only): the map, the queries, the absent ones, the taxonomy, every row
    prov = on_disk["classifiers"]["provenance"]
    assert prov["map"]["path"] == str(scene / "scene.npz")
    assert sorted(prov["queries"]) == ["chair", "floor", "wall"] and prov["absent"] == ["piano"]
    assert prov["taxonomy"] == str(scene / "scene.taxonomy.yaml")
    assert sorted(c["name"] for c in prov["configs"]) == sorted(_names(rows))


def test_fair_table_gives_the_label_list_to_the_peers_and_says_so(scene, tmp_path):
    from quash_plugins.evaluation.ablations import FAIR

    tax = str(scene / "scene.taxonomy.yaml")
    cfgs = bench_configs(tax, ENCODER)["fair"]
    assert _names(cfgs)[: len(FAIR)] == [c["name"] for c in cfgs]
    lists = [c for c in cfgs if c["heuristic"] != "none" and c["heuristic"]["name"] != "none"]
    # every label-list method (the peers' argmax and QuASH) gets the same file
    assert {c["name"] for c in lists} >= {"vlmaps-labels", "openscene-labels", "quash-labels"}
    assert all(c["heuristic"]["file"] == tax for c in lists)
    results = run_bench(
        scene / "scene.npz",
        tax,
        tmp_path / "f",
        tables=("fair",),
        encoder=ENCODER,
        overrides={"cache": False},
        absent=("piano",),
    )
    rows = {r["name"]: r for r in results["fair"]["configs"]}
    assert list(rows) == [c["name"] for c in cfgs]  # peers first, not sorted by F1
    assert rows["vlmaps"]["given"] == "the query alone"
    assert rows["vlmaps-labels"]["given"] == rows["quash-labels"]["given"]
    assert rows["quash-labels"]["given"] == "the label list (scene.taxonomy.yaml)"
    md = (tmp_path / "f" / "bench.md").read_text()
    assert "| quash-labels | the label list (scene.taxonomy.yaml) |" in md


@pytest.mark.parametrize(
    "args,message",
    [
        (["--tables", "antonym"], "Unknown table 'antonym'; known: prompt, antonyms"),
        (["--taxonomy", "missing.yaml"], "Taxonomy file not found: missing.yaml"),
    ],
)
def test_bench_usage_errors(scene, tmp_path, capsys, args, message):
    code = main(["bench", str(scene / "scene.npz"), "--out", str(tmp_path / "o"), *args])
    assert code == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_bench_missing_taxonomy_names_a_near_file_and_the_fix(scene, tmp_path, capsys):
    """'Taxonomy file not found: PATH' gave no fix: --taxonomy's file is now answered,
    as a heuristic's is, with a file beside it with a near name and what to give."""
    (tmp_path / "tax.yml").write_text("chair: [armchair]\n")
    args = ["bench", str(scene / "scene.npz"), "--out", str(tmp_path / "o")]
    assert main([*args, "--taxonomy", str(tmp_path / "tax.yaml")]) == 2
    err = " ".join(capsys.readouterr().err.split())
    assert f"Taxonomy file not found: {tmp_path / 'tax.yaml'}. Did you mean " in err
    assert f"{tmp_path / 'tax.yml'}? --taxonomy names it: give a YAML file of {{label:" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "args,message",
    [
        (["--absent", "Wall"], "Absence query 'Wall' (--absent): "),
        # a present query given again as absent in another case; its spacing made single
        (
            ["--queries", "a seat=chair", "--absent", "A   Seat"],
            "'a seat' is a present query (the queries) and 'A Seat', the same query in another",
        ),
        (["--queries", "bunk bed="], "write an open-vocabulary query as TEXT=LABEL"),
        (["--queries", "a=b=bed"], "holds more than one '='"),
        (["--queries", " , "], "--queries is empty"),  # as quash eval refuses it
        (["--tables", " "], "--tables is empty"),  # was: {} written over earlier results
        # an empty string is refused with the usage, as for every option (argparse exits)
        (["--queries", ""], "argument --queries: an empty value"),
        (["--tables", ""], "argument --tables: an empty value"),
    ],
)
def test_bench_refuses_a_query_list_before_any_table(scene, tmp_path, capsys, args, message):
    # was: every row of every table 'skipped' with the same note, and exit status 0
    try:
        code = main(["bench", str(scene / "scene.npz"), "--out", str(tmp_path / "o"), *args])
    except SystemExit as exc:
        code = exc.code
    assert code != 0
    assert message in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_taxonomy_that_is_a_query_file_is_refused_before_any_table(scene, tmp_path, capsys):
    """make-scene's SCENE.queries.yaml given as --taxonomy: every taxonomy row was
    'skipped' with the same note and bench exited 0; it is refused, naming the file."""
    queries = scene / "scene.queries.yaml"
    code = main(
        ["bench", str(scene / "scene.npz"), "--out", str(tmp_path / "o")]
        + ["--taxonomy", str(queries), "--tables", "classifiers"]
    )
    assert code != 0
    err = " ".join(capsys.readouterr().err.split())
    assert f"--taxonomy {queries} is not a taxonomy" in err
    assert "{label: [sub-class, ...]}" in err
    assert not (tmp_path / "o").exists()


def test_llm_rows_read_the_cache_of_the_endpoint_given(scene, tmp_path, capsys):
    """The llm sets are cached by endpoint and model: a cache filled from Ollama's port
    (as lseg:quash-llm does) is read with --llm-base-url; with --llm-model alone the
    bench looked at the llm heuristic's default endpoint and skipped every llm row."""
    from quash_plugins.heuristics import LLM_DEFAULT_BASE_URL, LLMHeuristic

    # --help names the heuristic's own default endpoint
    assert inspect.signature(LLMHeuristic).parameters["base_url"].default == LLM_DEFAULT_BASE_URL
    url = "http://127.0.0.1:11434/v1"
    lmap = Quash.from_config({"encoder": ENCODER, "cache": False}).read_map(scene / "scene.npz")
    present = sorted({lmap.label_names[i] for i in np.unique(lmap.labels)} - set(DEFAULT_EXCLUDE))
    filler = LLMHeuristic(model="m", base_url=url, offline=True)
    for q in present:
        filler._write_cache(q, [f"{q} seat", "furniture"], ["ceiling", "floor"])
    base = ["bench", str(scene / "scene.npz"), "--encoder", ENCODER, "--no-cache"]
    base += ["--tables", "sources", "--llm-model", "m"]

    assert main([*base, "--out", str(tmp_path / "a"), "--llm-base-url", url]) == 0
    data = json.loads((tmp_path / "a" / "bench.json").read_text())["sources"]
    names = _names(data["configs"])
    assert {"llm x llm", "llm x lexicon", "adjectives x llm"} <= set(names)
    # no --taxonomy: its rows are missing, and the table says so
    assert not any("taxonomy" in n for n in names)
    assert data["notes"] == ["- taxonomy rows skipped: give the taxonomy file (--taxonomy)."]

    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "b")]) == 0  # the default endpoint: a miss
    data = json.loads((tmp_path / "b" / "bench.json").read_text())["sources"]
    assert not any("llm" in n for n in _names(data["configs"]))
    assert any(f"endpoint {LLM_DEFAULT_BASE_URL}/chat/completions" in n for n in data["notes"])


def test_llm_base_url_without_a_model_is_refused(scene, tmp_path, capsys):
    args = ["bench", str(scene / "scene.npz"), "--out", str(tmp_path / "o")]
    assert main([*args, "--llm-base-url", "http://127.0.0.1:11434/v1"]) == 2
    assert "--llm-base-url needs --llm-model" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_run_bench_reports_progress_through_each_tables_configs(
    scene, tmp_path, caplog, monkeypatch
):
    """A table ran every config with nothing said until 'table X: done' (the classifiers
    table: 51 s on a 56k-voxel scene); each config now advances the table's progress."""
    import logging

    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    with caplog.at_level(logging.INFO, logger="quash_plugins.progress"):
        run_bench(
            scene / "scene.npz",
            str(scene / "scene.taxonomy.yaml"),
            tmp_path / "b",
            tables=("classifiers",),
            encoder=ENCODER,
            overrides={"cache": False},
            queries=["wall", "chair"],
        )
    n = len(bench_configs(str(scene / "scene.taxonomy.yaml"), ENCODER)["classifiers"])
    lines = [r.getMessage() for r in caplog.records if r.name == "quash_plugins.progress"]
    assert any(m.startswith(f"table classifiers: {n} config(s): 1/{n} ") for m in lines), lines
    assert any(f": {n}/{n} (100%" in m for m in lines), lines


def test_bench_reads_a_query_file_as_quash_eval_does(scene, tmp_path, capsys):
    """A held-out query file (open-vocabulary TEXT: LABEL items and an absent list) could
    reach bench only through --queries/--absent, where a text with a comma cannot go."""
    q = tmp_path / "held-out.yaml"
    q.write_text(
        "present:\n  somewhere to sit, by the window: chair\n  a partition: wall\n"
        "absent: [a grand piano]\n"
    )
    out = tmp_path / "o"
    args = ["bench", str(scene / "scene.npz"), "--out", str(out), "--tables", "antonyms"]
    args += ["--encoder", ENCODER, "--no-cache"]
    assert main([*args, "--queries-file", str(q), "--absent", "an elephant"]) == 0
    data = json.loads((out / "bench.json").read_text())["antonyms"]
    assert data["configs"] and not data["notes"]
    for row in data["configs"]:
        labels = {text: m["label"] for text, m in row["per_query"].items()}
        assert labels == {"somewhere to sit, by the window": "chair", "a partition": "wall"}
        assert list(row["absence"]["per_query"]) == ["a grand piano", "an elephant"]
    prov = data["provenance"]
    assert prov["query_file"] == str(q)
    assert prov["queries"] == {"somewhere to sit, by the window": "chair", "a partition": "wall"}
    assert prov["absent"] == ["a grand piano", "an elephant"]
    # the same file's mistake is refused before any table, naming the file
    bad = tmp_path / "bad.yaml"
    bad.write_text("presnt:\n  a partition: wall\nabsent: [a grand piano]\n")
    capsys.readouterr()
    assert main([*args[:3], str(tmp_path / "o2"), *args[4:], "--queries-file", str(bad)]) != 0
    assert f"{bad}: unknown key 'presnt'" in capsys.readouterr().err
    assert not (tmp_path / "o2").exists()
    # --queries and --queries-file exclude each other, as in quash eval
    with pytest.raises(SystemExit):
        main([*args, "--queries", "chair", "--queries-file", str(q)])
    assert "not allowed with argument" in capsys.readouterr().err
