"""Absent objects that the label list does not hold: the opt-in ``unlisted`` rule.

A robot's label list names what the map was built with; a person may ask for an object
that is neither in the map nor in the list ("fireplace" on a list without one). Resolving
such a query by embedding puts it on the nearest label ("stove"), whose object is there.
This benchmark gives every label-list method the map's label names **only** (no
sub-classes, and none of the absent labels), queries the present labels, and queries the
taxonomy's absent labels as absence queries. Re-run with::

    .venv/bin/python benchmarks/bench_unlisted.py --out bench-quality --seeds 0,1,2,3,4

(scenes are those of ``bench_quality.py`` under ``DIR/scenes``, built when missing;
``--generators`` picks a subset). Rows: QuASH (``demo:quash-labels``) as shipped and with
``unlisted: vocabulary``, and the two fair peers (``demo:vlmaps-labels``,
``demo:openscene-labels``) as shipped. It also counts, over each scene's open-vocabulary
queries (``SCENE.open-queries.yaml``) on the same list, the resolutions that the rule
changes: a present query's correct label lost ("couch" -> sofa), or an absent object's
wrong label dropped. It writes ``DIR/unlisted.md`` and ``DIR/unlisted.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import yaml
from bench_quality import GENERATORS, parse_seeds, scene

from quash_plugins.core import registry
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.core.shipped import find_shipped
from quash_plugins.engine import open_cache
from quash_plugins.evaluation.report import evaluate, load_query_file
from quash_plugins.heuristics import TaxonomyHeuristic

METHODS = (
    "quash-labels",
    "quash-labels (unlisted: vocabulary)",
    "vlmaps-labels",
    "openscene-labels",
)


def configs(label_names: list[str]) -> list[dict]:
    """The label-list configs, each given the map's label names alone (in memory, so a
    taxonomy beside the map is not read)."""
    listed = {name: [] for name in label_names}
    out = []
    for method in METHODS:
        shipped, _, variant = method.partition(" (")
        cfg = find_shipped(f"demo:{shipped}").data()
        h = {k: v for k, v in dict(cfg["heuristic"]).items() if k != "file"}
        h["taxonomy"] = listed
        if variant:
            h["unlisted"] = "vocabulary"
            cfg["name"] = method
        cfg["heuristic"] = h
        out.append(cfg)
    return out


def resolution_changes(stem: Path, names: list[str], encoder, cache) -> dict:
    """How ``unlisted: vocabulary`` changes the resolution of the scene's open-vocabulary
    queries on the list of label names."""
    listed = {name: [] for name in names}
    ctx = ExpansionContext(encoder=encoder, extra={"cache": cache})
    before = TaxonomyHeuristic(taxonomy=listed)
    after = TaxonomyHeuristic(taxonomy=listed, unlisted="vocabulary")
    present, absent = load_query_file(Path(f"{stem}.open-queries.yaml"))
    out = {
        "queries": len(present) + len(absent),
        "lost": [],
        "wrong_dropped": [],
        "absent_dropped": [],
    }
    for q in [*present, *absent]:
        old, new = before.resolve_query(q, ctx)["to"], after.resolve_query(q, ctx)["to"]
        if old == new:
            continue
        truth = present.get(q)
        key = "absent_dropped" if truth is None else "lost" if old == truth else "wrong_dropped"
        out[key].append(f"{q} -> {old}")
    return out


def run_one(out: Path, generator: str, seed: int, encoder, cache) -> dict:
    res = out / "runs" / f"{generator}-seed{seed}-unlisted.json"
    if res.exists():
        return json.loads(res.read_text(encoding="utf-8"))
    path = scene(out, generator, seed, encoder, cache)
    stem = path.with_suffix("")
    names = [str(n) for n in np.load(path, allow_pickle=True)["label_names"]]
    present = list(yaml.safe_load(Path(f"{stem}.queries.yaml").read_text("utf-8"))["present"])
    tax = yaml.safe_load(Path(f"{stem}.taxonomy.yaml").read_text(encoding="utf-8"))
    absent = [t for t in tax if t not in names]
    t = time.perf_counter()
    rep = evaluate(str(path), configs(names), queries={q: q for q in present}, absent=absent)
    rec = {
        "generator": generator,
        "seed": seed,
        "seconds": round(time.perf_counter() - t, 1),
        "absent": absent,
        "resolutions": resolution_changes(stem, names, encoder, cache),
        "configs": [
            {
                "name": c["name"],
                "f1": c["mean"]["f1"],
                "recall": c["mean"]["recall"],
                "absence": c["absence"]["score"],
                "matched": {q: v["matched"] for q, v in c["absence"]["per_query"].items()},
            }
            for c in rep.configs
        ],
    }
    res.parent.mkdir(parents=True, exist_ok=True)
    res.write_text(json.dumps(rec) + "\n", encoding="utf-8")
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-quality")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--generators", default=",".join(GENERATORS))
    args = ap.parse_args()
    out = Path(args.out)
    seeds = parse_seeds(args.seeds)
    gens = [g for g in args.generators.split(",") if g]
    if bad := [g for g in gens if g not in GENERATORS]:
        raise SystemExit(f"unknown generator: {bad[0]}")
    encoder, cache = registry.create("encoders", "minilm"), open_cache(True)
    md = [
        f"# Absent objects missing from the label list: seeds {', '.join(map(str, seeds))}",
        "",
        "Every method is given the map's label names only (no sub-classes, no absent label).",
        "Mean ± standard deviation over seeds; *absent matched*: absence queries (over all",
        "seeds) that matched something.",
        "",
        "| generator | method | F1 | recall | absence | absent matched |",
        "|---|---|---|---|---|---|",
    ]
    summary: dict = {}
    runs: dict[str, list[dict]] = {}
    for gen in gens:
        recs = runs[gen] = []
        for seed in seeds:
            recs.append(run_one(out, gen, seed, encoder, cache))
            print(f"{gen} seed {seed}: {recs[-1]['seconds']} s", flush=True)
        for method in METHODS:
            rows = [c for r in recs for c in r["configs"] if c["name"] == method]
            stats = {
                k: np.asarray([c[k] for c in rows], float) for k in ("f1", "recall", "absence")
            }
            hits = sorted({q for c in rows for q, n in c["matched"].items() if n})
            bad = sum(1 for c in rows for n in c["matched"].values() if n)
            total = sum(len(c["matched"]) for c in rows)
            summary[f"{gen}|{method}"] = {k: v.tolist() for k, v in stats.items()}
            cells = " | ".join(f"{v.mean():.3f} ± {v.std():.3f}" for v in stats.values())
            md.append(
                f"| {gen} | {method} | {cells} | {bad}/{total}"
                + (f" ({', '.join(hits)})" if hits else "")
                + " |"
            )
    md += [
        "",
        "Open-vocabulary queries (`SCENE.open-queries.yaml`) on the same list: resolutions",
        "that `unlisted: vocabulary` changes (over all seeds). *lost*: a present query's",
        "correct label; *wrong dropped*: a present query's wrong label; *absent dropped*: an",
        "absent object's label.",
        "",
        "| generator | queries | lost | wrong dropped | absent dropped | examples lost |",
        "|---|---|---|---|---|---|",
    ]
    for gen in gens:
        res = [rec["resolutions"] for rec in runs[gen]]
        n = {k: sum(len(r[k]) for r in res) for k in ("lost", "wrong_dropped", "absent_dropped")}
        examples = sorted({x for r in res for x in r["lost"]})[:4]
        md.append(
            f"| {gen} | {sum(r['queries'] for r in res)} | {n['lost']} | {n['wrong_dropped']} "
            f"| {n['absent_dropped']} | {'; '.join(examples)} |"
        )
        summary[f"{gen}|resolutions"] = n
    out.mkdir(parents=True, exist_ok=True)
    (out / "unlisted.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / "unlisted.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    print("\n".join(md))


if __name__ == "__main__":
    main()
