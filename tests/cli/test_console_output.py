"""What the commands print: progress that adds up, shared costs said to be shared, tables
sized to the terminal, log lines that never wrap."""

from __future__ import annotations

import re

import pytest
from rich.console import Console

from quash_plugins.cli._output import print_markdown
from quash_plugins.cli.main import main


def refine_config(world, min_seed: int = 10):
    cfg = world["dir"] / f"refine-{min_seed}.yaml"
    cfg.write_text(
        "name: refined\n"
        f"encoder: {{name: table, file: {world['table'].name}}}\n"
        "heuristic: none\n"
        "classifier: {name: nearest-sample, k: 2}\n"
        f"refine: {{classifier: svm-rbf, n_positives: 20, n_negatives: 50, min_seed: {min_seed}}}\n"
        "cache: false\n"
    )
    return cfg


@pytest.mark.parametrize("min_seed", [10, 10_000], ids=["refined", "refine-skipped"])
def test_progress_adds_up_to_the_passes(tiny_world, min_seed):
    """The refinement's second pass counts in the total (the bar read 200 % before)."""
    from quash_plugins import Quash

    quash = Quash.from_config(refine_config(tiny_world, min_seed))
    assert quash.passes == 2
    done = []
    results = quash.query_many(tiny_world["map"], ["chair", "sofa"], progress=done.append)
    assert sum(done) == 600 * quash.passes
    refined = [r.queryset.provenance["refine"]["applied"] for r in results]
    assert refined == [min_seed == 10] * 2
    for r in results:
        # The second pass is reported apart from the re-fit, as each query's share.
        assert ("reclassify" in r.timings) == (min_seed == 10)
        assert r.timings["classify"] == results[0].timings["classify"]


def test_query_progress_never_passes_100_percent(tiny_world, capsys, monkeypatch):
    monkeypatch.setattr("quash_plugins.core.progress.MIN_INTERVAL", 0.0)  # fast here
    code = main(
        ["query", str(tiny_world["map"]), "chair", "sofa", "-c", str(refine_config(tiny_world))]
    )
    out = capsys.readouterr()
    assert code == 0, out.err
    lines = re.findall(r"classifying 600 items \(2 passes\): (\d+)/(\d+) \((\d+)%", out.err)
    assert lines, out.err
    assert {int(total) for _, total, _ in lines} == {1200}
    assert all(int(pct) <= 100 for *_, pct in lines) and lines[-1][2] == "100"
    # Shared stages are marked, and their whole cost is given once.
    assert "classify*" in out.out and "reclassify*" in out.out
    assert re.search(r"done once for all the queries.*classify [\d.]+ ms for 2", out.out, re.S)


def test_the_stage_table_shows_every_stage_the_query_timed(tiny_world, capsys):
    """The presence check's time is in the query's total: its row was missing, so the
    stages did not add up to the time column (the default config has the check on)."""
    cfg = tiny_world["dir"] / "presence.yaml"
    cfg.write_text(
        tiny_world["config"].read_text().replace("name: vlmaps-contrast", "name: checked")
        + "presence: {}\n"
    )
    from quash_plugins import Quash

    [r] = Quash.from_config(cfg).query_many(tiny_world["map"], ["chair"])
    stages = [s for s in r.timings if s != "total"]
    assert "presence" in stages
    code = main(["query", str(tiny_world["map"]), "chair", "-c", str(cfg)])
    out = capsys.readouterr()
    assert code == 0, out.err
    table = out.out[out.out.index("time per stage (ms)") :]
    for stage in stages:
        assert re.search(rf"^\s*{stage}\*?\s+[\d.]+\s*$", table, re.M), (stage, table)


WIDE = """# Report

| query | vlmaps | conceptfusion | lerf | quash-taxonomy | quash-taxonomy-svm | quash-adjectives |
|---|---:|---:|---:|---:|---:|---:|
| refrigerator | 0.026 | 0.330 | 0.034 | **0.893** | 0.000 | 0.039 |
| chair | 0.048 | 0.465 | 0.057 | 0.813 | 0.000 | 0.062 |

Items matched by absence queries (0 = correct):
"""


def test_markdown_tables_print_as_tables_that_fit_the_terminal():
    console = Console(width=72, record=True, highlight=False)
    print_markdown(console, WIDE)
    text = console.export_text()
    lines = text.splitlines()
    assert max(len(ln.rstrip()) for ln in lines) <= 72
    assert not any("|" in ln for ln in lines), text  # no Markdown pipes on screen
    assert "---" not in text
    rows = [ln for ln in lines if ln.lstrip().startswith(("refrigerator", "chair"))]
    # each row on one line, the first column whole, in each part of the too wide table
    assert len(rows) == 4 and "too wide for 72 columns" in text
    assert "0.893" in rows[0] and "**" not in text
    assert lines[0] == "Report" and "Items matched by absence queries (0 = correct):" in text


def test_demo_prints_tables_not_markdown(tmp_path, capsys):
    pytest.importorskip("sentence_transformers")
    assert main(["demo", "--tiny", "--no-rrd", "--out", str(tmp_path / "d")]) == 0
    out = capsys.readouterr().out
    assert "|---" not in out and "| quash-taxonomy |" not in out
    assert re.search(r"^\s*quash-taxonomy\s+0\.\d{3}", out, re.M), out
    assert "|---" in (tmp_path / "d" / "demo.md").read_text()  # Markdown stays for files


def test_log_lines_do_not_wrap_off_a_terminal(capsys):
    import logging

    from quash_plugins.cli._output import setup_logging

    setup_logging(0, False)
    message = "a long warning " * 12
    logging.getLogger("quash_plugins.test").warning(message.strip())
    err = capsys.readouterr().err
    assert err == f"WARNING  {message.strip()}\n"


def test_a_given_column_prints_as_its_own_table_and_numbers_never_fold():
    from rich.console import Console

    from quash_plugins.cli._output import print_markdown

    long = "the label list (the map's label names + scene-v1-full-seed0-minilm.taxonomy.yaml)"
    md = (
        "| method | given | F1 | precision | recall | IoU | AP | inv. rank | absence "
        "| present -> empty |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
        "| vlmaps | the query alone | 0.032 | 0.016 | 0.994 | 0.016 | 0.562 | 0.917 | 0.000 "
        "| 0/10 |\n"
        f"| quash-labels | {long} | 0.748 | 0.754 | 0.747 | 0.706 | 0.759 | 0.803 | 1.000 "
        "| 2/10 |\n"
    )
    console = Console(width=80, record=True)
    print_markdown(console, md)
    lines = console.export_text().splitlines()
    assert all(len(line) <= 80 for line in lines)
    numbers = [ln for ln in lines if ln.startswith("quash-labels") and "0.748" in ln]
    assert len(numbers) == 1 and numbers[0].split()[1:] == [
        "0.748", "0.754", "0.747", "0.706", "0.759", "0.803", "1.000", "2/10"
    ]  # fmt: skip
    given = [ln for ln in lines if ln.startswith("quash-labels") and "the label list" in ln]
    assert len(given) == 1 and "0.748" not in given[0]


SUMMARY = (
    "| method | F1 | precision | recall | IoU | AP | inv. rank | absence | present -> empty |\n"
    "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n"
    "| openscene-labels | 0.569 | 0.630 | 0.597 | 0.449 | 0.748 | 1.000 | n/a | 2/17 |\n"
    "| quash-labels | **0.845** | 0.808 | 0.909 | 0.743 | 0.906 | 0.972 | 1.000 | 0/17 |\n"
)
HEADER_WORDS = ["method", "F1", "precision", "recall", "IoU", "AP", "inv.", "rank"]
HEADER_WORDS += ["absence", "present", "->", "empty"]


def _printed(md: str, width: int) -> list[str]:
    console = Console(width=width, record=True, highlight=False)
    print_markdown(console, md)
    return console.export_text().splitlines()


@pytest.mark.parametrize("width", [120, 100, 80, 72, 60, 40])
def test_table_headers_wrap_only_at_spaces_and_no_column_is_cut(width):
    """At 80 columns the summary read 'precisi / on' and 'presen / t -> empty'."""
    lines = _printed(SUMMARY, width)
    text = "\n".join(lines)
    assert max(len(ln) for ln in lines) <= width, text
    words = {w for ln in lines for w in ln.split()}
    assert set(HEADER_WORDS) <= words, text  # every header word whole
    for row in ("openscene-labels", "quash-labels"):
        cells = [w for ln in lines if ln.startswith(row) for w in ln.split()[1:]]
        expected = SUMMARY.split(f"| {row} | ")[1].split("\n")[0].replace("*", "")
        assert cells == [c.strip() for c in expected.strip(" |").split("|")], text
    if width >= 80:
        assert "too wide" not in text  # fits whole, in one table
    else:
        assert f"too wide for {width} columns" in text


def test_many_configs_side_by_side_print_in_parts_with_a_note():
    lines = _printed(WIDE, 72)
    text = "\n".join(lines)
    assert max(len(ln) for ln in lines) <= 72
    assert "too wide for 72 columns: it is shown in 2 parts" in text
    names = ["vlmaps", "conceptfusion", "lerf", "quash-taxonomy", "quash-taxonomy-svm"]
    assert set(names + ["quash-adjectives"]) <= {w for ln in lines for w in ln.split()}
    rows = [ln.split() for ln in lines if ln.startswith("refrigerator")]
    assert [c for r in rows for c in r[1:]] == [
        "0.026",
        "0.330",
        "0.034",
        "0.893",
        "0.000",
        "0.039",
    ]


def test_eval_at_80_columns_breaks_no_header_word(minilm_scene, monkeypatch, capsys):
    """The walkthrough: COLUMNS=80 quash eval MAP -c demo:openscene-labels."""
    monkeypatch.setenv("COLUMNS", "80")
    args = ["eval", str(minilm_scene), "-c", "demo:openscene-labels", "--absent", "piano"]
    assert main(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert max(len(ln) for ln in lines) <= 80
    words = {w for ln in lines for w in ln.split()}
    assert set(HEADER_WORDS) <= words
    assert not {"precisi", "on", "presen", "t"} & words
    (row,) = [ln.split() for ln in lines if ln.startswith("openscene-labels") and "0." in ln]
    assert len(row) == 9 and "/" in row[-1]  # the last column, present -> empty, is there


def _config(name: str, f1s: dict[str, tuple[str, float]], absent: dict[str, str]) -> dict:
    """A report's config entry as evaluate() writes it (the fields the tables read)."""
    per_query = {q: {"label": label, "f1": f1} for q, (label, f1) in f1s.items()}
    mean = {k: 0.5 for k in ("precision", "recall", "f1", "iou", "ap", "inv_rank")}
    return {
        "name": name,
        "given": "the label list (the map's label names)",
        "mean": mean,
        "per_query": per_query,
        "absence": {
            "score": 1.0,
            "empty_tolerance": 0,
            "present_empty": 0,
            "per_query": {
                q: {"label": label, "matched": 0, "empty": True} for q, label in absent.items()
            },
        },
    }


@pytest.mark.parametrize("width", [80, 72, 40])
def test_a_label_cell_never_breaks_inside_a_name(width):
    """At 80 columns the label 'tv monitor' of 'a television screen=tv monitor' printed
    as 'tv' over 'monitor', which reads as two labels. At 40 it cannot stand beside the
    query, and wraps at its spaces."""
    from quash_plugins.evaluation.report import report_markdown

    labels = {
        "a television screen": "tv monitor",
        "somewhere to put clothes": "chest of drawers",
        "bunk bed": "bed",
    }
    names = ["vlmaps-labels", "openscene-labels", "quash-labels", "quash-taxonomy"]
    configs = [
        _config(
            n, {q: (lab, 0.1 * (i + 1)) for q, lab in labels.items()}, {"a grand piano": "piano"}
        )
        for i, n in enumerate(names)
    ]
    lines = _printed(report_markdown(configs), width)
    text = "\n".join(lines)
    words = {w for ln in lines for w in ln.split()}
    assert {w for label in labels.values() for w in label.split()} <= words, text
    if width < len("somewhere to put clothes chest of drawers"):
        # no room for the label on one line beside the query: it wraps at its spaces,
        # never cut ('chest of drawer')
        return
    assert max(len(ln.rstrip()) for ln in lines) <= width, text
    for query, label in labels.items():
        rows = [ln for ln in lines if ln.startswith(query)]
        assert rows and re.match(rf"{query}\s+{label}\s", rows[0]), text
        # the line below the query's row is not the rest of its label
        below = lines[lines.index(rows[0]) + 1].split()
        assert not below or below[0] not in label.split()[1:], text
    # every config's F1 of every query is still printed whole
    values = {w for ln in lines for w in ln.split()}
    assert {"0.100", "0.200", "0.300", "0.400"} <= values, text
    assert set(names) <= values, text


def test_a_markdown_image_prints_as_its_path():
    console = Console(width=80, record=True, highlight=False)
    print_markdown(console, "## Fair\n\n![The fair protocol](fair.png)\n", base="out/bench")
    text = console.export_text()
    assert "![" not in text and "plot: out/bench/fair.png" in text


@pytest.mark.parametrize("width", [80, 140])
def test_the_stage_table_of_many_queries_never_breaks_a_number(width):
    """More queries than columns: one row per query. On 80 columns (a pipe, CI) every
    number was folded over lines ("24." above "9"); each now stands whole on its row."""
    from types import SimpleNamespace

    from quash_plugins.cli._output import STAGES, timings_table

    stages = [*STAGES, "presence", "instances"]
    queries = [
        "chair",
        "a very long query about somewhere to sleep",
        "tv",
        "bed",
        "sofa",
        "lamp",
        "sink",
    ]
    results = [
        SimpleNamespace(
            query=q, timings={s: 0.0249 + 0.01 * i + 0.001 * j for i, s in enumerate(stages)}
        )
        for j, q in enumerate(queries)
    ]
    console = Console(width=width, record=True, highlight=False)
    console.print(timings_table(results, width=width))
    lines = console.export_text().splitlines()
    assert max(len(ln.rstrip()) for ln in lines) <= width
    for j, q in enumerate(queries):
        ms = [1000 * (0.0249 + 0.01 * i + 0.001 * j) for i in range(len(stages))]
        expect = [f"{v:.0f}" if v >= 100 else f"{v:.1f}" for v in ms]
        [row] = [ln for ln in lines if ln.split()[:1] == q.split()[:1]]
        assert row.split()[-len(stages) :] == expect, (q, row)


def test_a_query_that_matches_nothing_without_the_presence_check_says_by_how_much(
    tiny_world, capsys
):
    """The presence check off (the paper's SVM, a hand-set threshold): an empty answer
    said nothing, as if the query had not run; it now gives the best score and the
    threshold it missed."""
    from quash_plugins import Quash

    cfg = tiny_world["dir"] / "high.yaml"
    cfg.write_text(tiny_world["config"].read_text() + "threshold: 50.0\n")
    [r] = Quash.from_config(cfg).query_many(tiny_world["map"], ["chair"])
    assert r.n_matched == 0 and r.presence == "off"
    code = main(["query", str(tiny_world["map"]), "chair", "-c", str(cfg)])
    out = " ".join(capsys.readouterr().out.split())
    assert code == 0
    best = f"{float(r.scores.max()):.3g}"
    assert f"'chair' matched nothing: its highest score is {best}, under the threshold 50" in out
    # a query that matches says nothing of the kind
    assert main(["query", str(tiny_world["map"]), "chair", "-c", str(tiny_world["config"])]) == 0
    assert "matched nothing" not in capsys.readouterr().out
