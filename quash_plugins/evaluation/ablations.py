"""The ablation runner: the paper's tables on a labelled map, as Markdown and PNG plots.

Tables (each one :func:`~quash_plugins.evaluation.report.evaluate` call; the paper's
Tables III, IV and V, then two of ours; what differs from the paper and why is in
docs/benchmarks.md):

1. prompt engineering on/off, for the paper's baseline (``contrast`` against "other")
   and QuASH (taxonomy, nearest-sample);
2. antonym words for the contrast baseline: other, others, background, texture, stuff,
   nothing, object, things and the zero vector (``<zero>``);
3. synonym source x antonym source over taxonomy, adjectives, lexicon and llm (the llm
   only from its cache, ``offline: true``; skipped with a note when the cache is empty);
4. classifiers on the taxonomy query sets;
5. ``fair``: the peers' rules and QuASH, each given what it is given in the fair protocol
   (docs/benchmarks.md): VLMaps, ConceptFusion and LERF the query alone; VLMaps with its
   category list and OpenScene's label argmax the same label list as QuASH (``--taxonomy``,
   else the map's label names with the taxonomy beside the map); the shipped configs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any

from ..core.errors import QuashError
from ..core.shipped import LIST_PEERS, QUERY_PEERS, find_shipped
from ..core.text import ZERO_TOKEN
from .plot import plot_precision_recall
from .report import evaluate, plan_queries, report_markdown

log = logging.getLogger(__name__)

ANTONYMS = (
    "other",
    "others",
    "background",
    "texture",
    "stuff",
    "nothing",
    "object",
    "things",
    ZERO_TOKEN,
)
SOURCES = ("taxonomy", "adjectives", "lexicon", "llm")
QUASH_CLASSIFIER: dict[str, Any] = {"name": "nearest-sample", "k": 2}
CLASSIFIERS: dict[str, Any] = {
    "nearest-sample k=1 (= contrast)": {"name": "nearest-sample", "k": 1},
    "nearest-sample k=2": {"name": "nearest-sample", "k": 2},
    "nearest-sample k=3": {"name": "nearest-sample", "k": 3},
    "nearest-sample k=5": {"name": "nearest-sample", "k": 5},
    "svm-rbf": "svm-rbf",
    "svm-rbf balanced": {"name": "svm-rbf", "class_weight": "balanced"},
    "svm-cosine": "svm-cosine",
    "lerf-relevancy": "lerf-relevancy",
}
TABLES = ("prompt", "antonyms", "sources", "classifiers", "fair")
#: The shipped configs of the fair table, peers first (quash_plugins/data/configs/demo-*).
FAIR = (*QUERY_PEERS, *LIST_PEERS, "quash-labels", "quash-taxonomy", "quash-taxonomy-svm")


def shipped(name: str) -> dict[str, Any]:
    """The shipped config ``demo:<name>`` as a dict."""
    return find_shipped(f"demo:{name}").data()


def _cfg(name: str, encoder: Any, heuristic: Any, classifier: Any, **extra: Any) -> dict:
    return {
        "name": name,
        "encoder": encoder,
        "heuristic": heuristic,
        "classifier": classifier,
        "instances": False,
        **extra,
    }


def _source_spec(source: str, taxonomy: str | None, llm: dict[str, Any] | None) -> Any:
    # The paper samples 100 antonyms; 200 gives the query sets of the shipped
    # demo-quash-taxonomy config, so these rows compare with its fair-table row
    # (docs/benchmarks.md, "How these tables compare with the paper's").
    if source == "taxonomy":
        return {"name": "taxonomy", "file": taxonomy, "n_synonyms": 20, "n_antonyms": 200}
    if source == "llm":
        return {"name": "llm", "offline": True, **(llm or {})}
    return source


def bench_configs(
    taxonomy: str | None, encoder: Any = "minilm", llm: dict[str, Any] | None = None
) -> dict[str, list[dict[str, Any]]]:
    """The configs of every table (dicts, ready for :meth:`Quash.from_config`)."""
    tax = _source_spec("taxonomy", taxonomy, llm)
    pe = {"mode": "mean"}
    tables: dict[str, list[dict[str, Any]]] = {}
    tables["prompt"] = [
        _cfg("baseline PE", encoder, "none", "contrast", negatives=["other"], prompt_templates=pe),
        _cfg("baseline no PE", encoder, "none", "contrast", negatives=["other"]),
    ]
    if taxonomy:
        tables["prompt"] += [
            _cfg("quash-taxonomy PE", encoder, tax, QUASH_CLASSIFIER, prompt_templates=pe),
            _cfg("quash-taxonomy no PE", encoder, tax, QUASH_CLASSIFIER),
        ]
    tables["antonyms"] = [
        _cfg(
            f"baseline {'zero vector' if a == ZERO_TOKEN else a}",
            encoder,
            "none",
            "contrast",
            negatives=[a],
            **({} if a == ZERO_TOKEN else {"prompt_templates": pe}),
        )
        for a in ANTONYMS
    ]
    sources = [s for s in SOURCES if (s != "taxonomy" or taxonomy) and (s != "llm" or llm)]
    tables["sources"] = [
        _cfg(
            f"{s} x {a}",
            encoder,
            {
                "name": "combine",
                "synonyms": _source_spec(s, taxonomy, llm),
                "antonyms": _source_spec(a, taxonomy, llm),
            },
            QUASH_CLASSIFIER,
        )
        for s in sources
        for a in sources
    ]
    if taxonomy:
        tables["classifiers"] = [
            _cfg(f"taxonomy + {k}", encoder, tax, v) for k, v in CLASSIFIERS.items()
        ] + [
            _cfg(
                f"taxonomy + nearest-sample k=2 + refine ({r})",
                encoder,
                tax,
                QUASH_CLASSIFIER,
                refine={"classifier": r, "n_positives": 100, "n_negatives": 1000},
            )
            for r in ("svm-rbf", "nearest-sample")
        ]
    tables["fair"] = []
    for name in FAIR:
        cfg = {**shipped(name), "encoder": encoder}
        h = cfg.get("heuristic")
        if isinstance(h, dict) and h.get("name") in ("taxonomy", "label-list"):
            h = {k: v for k, v in h.items() if k != "file"}
            if taxonomy:  # the same label list for every label-list method
                h["file"] = taxonomy
            cfg["heuristic"] = h
        tables["fair"].append(cfg)
    return tables


def _check_taxonomy(taxonomy: str) -> None:
    """Refuse, before any table, a ``--taxonomy`` file that is not ``{label: [sub-class,
    ...]}`` (a query file given by mistake), naming the file and the fix."""
    from ..core import registry

    try:  # the taxonomy heuristic reads its file when it is built
        registry.create("heuristics", "taxonomy", file=str(taxonomy))
    except QuashError as exc:
        raise QuashError(
            f"--taxonomy {taxonomy} is not a taxonomy: {str(exc).splitlines()[0]} A "
            "taxonomy is YAML {label: [sub-class, ...]} (quash make-scene writes "
            "SCENE.taxonomy.yaml beside the map; SCENE.queries.yaml is a query file)."
        ) from exc


def _plot_title(title: str, rows: list[dict[str, Any]]) -> str:
    """A table's plot title: the table, then what each dot and mean is over (the present
    queries, and the absence queries the legend's absence score counts)."""
    n = max(len(r.get("per_query") or {}) for r in rows)
    m = max(len((r.get("absence") or {}).get("per_query") or {}) for r in rows)
    over = f"{n} quer{'y' if n == 1 else 'ies'}"
    if m:
        over += f", {m} absence quer{'y' if m == 1 else 'ies'}"
    return f"{title}\n{over}"


def run_bench(
    source: Any,
    taxonomy: str | None,
    out: str | Path,
    tables: tuple[str, ...] = TABLES,
    encoder: Any = "minilm",
    llm: dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
    queries: Any = None,
    absent: tuple[str, ...] = (),
    on_table: Callable[[str], None] | None = None,
    query_file: str | Path | None = None,
    absent_in_file: Collection[str] | None = None,
) -> dict[str, Any]:
    """Run the tables; write ``bench.md``, ``bench.json`` and ``<table>.png`` into ``out``.

    ``queries`` and ``absent`` are as :func:`~.report.evaluate` takes them (labels,
    ``TEXT=LABEL`` items or ``{text: label}``); ``query_file`` is the file they came
    from and ``absent_in_file`` the absence queries read from it (messages name it, and
    each table's provenance records it)."""
    import json

    from ..core.atomic import atomic_write_text
    from ..core.progress import progress
    from ..engine.pipeline import Quash

    out = Path(out)
    if taxonomy:  # not one: every taxonomy row would be skipped with the same note
        _check_taxonomy(taxonomy)
    all_cfgs = bench_configs(taxonomy, encoder, llm)
    overrides = dict(overrides or {})
    lmap = Quash.from_config(all_cfgs["prompt"][1], **overrides).read_map(source)
    where = {"query_file": query_file, "absent_in_file": absent_in_file}
    plan_queries(lmap, queries, absent=absent, **where)  # a list it cannot score: before any table
    out.mkdir(parents=True, exist_ok=True)
    results: dict[str, Any] = {}
    md = ["# quash bench", "", f"Map: {lmap.describe()}", ""]
    titles = {
        "prompt": "Prompt engineering (PE)",
        "antonyms": "Antonyms (baseline)",
        "sources": "Synonym source x antonym source",
        "classifiers": "Classifiers",
        "fair": "The fair protocol: every method with what it is given",
    }
    for table in tables:
        cfgs = all_cfgs.get(table)
        if not cfgs:
            md += [f"## {titles[table]}", "", "_skipped: needs --taxonomy_", ""]
            continue
        rows, notes = [], []
        provenance: dict[str, Any] = {}
        if table in ("prompt", "sources") and not taxonomy:
            notes.append("- taxonomy rows skipped: give the taxonomy file (--taxonomy).")
        if table == "sources" and not llm:
            notes.append("- llm rows skipped: give the model of a filled llm cache (--llm-model).")
        # one line every ~10 % of a table's configs: a table of ten configs on a large
        # map runs for minutes, and 'table X: done' comes only at its end
        with progress(len(cfgs), f"table {table}: {len(cfgs)} config(s)") as advance:
            for cfg in cfgs:
                try:
                    rep = evaluate(
                        lmap, [cfg], queries=queries, absent=absent, overrides=overrides, **where
                    )
                    rows.extend(rep.configs)
                    # what the table scored, as quash eval --json records it: the map,
                    # the queries, the absent ones and each row's config
                    seen = provenance.setdefault("configs", [])
                    provenance.update({k: v for k, v in rep.provenance.items() if k != "configs"})
                    seen.extend(rep.provenance.get("configs", []))
                except QuashError as exc:
                    notes.append(f"- {cfg['name']}: skipped ({str(exc).splitlines()[0]})")
                    log.warning("bench %s: %s skipped: %s", table, cfg["name"], exc)
                advance(1)
        if table != "fair":  # the fair table keeps the peers first, as the docs list them
            rows.sort(key=lambda c: -(c["mean"]["f1"] or 0.0))
        if provenance:
            provenance["taxonomy"] = str(taxonomy) if taxonomy else None
        results[table] = {"configs": rows, "notes": notes, "provenance": provenance}
        md += [f"## {titles[table]}", "", report_markdown(rows, per_query=False)]
        md += [*notes, ""] if notes else []
        if rows:
            plot_precision_recall(
                rows, out / f"{table}.png", title=_plot_title(titles[table], rows)
            )
            md += [f"![{titles[table]}]({table}.png)", ""]
        if on_table is not None:
            on_table(table)
    atomic_write_text(out / "bench.md", "\n".join(md) + "\n")
    atomic_write_text(out / "bench.json", json.dumps(results, indent=2) + "\n")
    return results
