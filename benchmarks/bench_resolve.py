"""Free text: how descriptions resolve to labels, and what each method does with each case.

A description ("where the milk is kept cold") is resolved to the label whose name (the
label or a sub-class) its text embedding is nearest to, when that cosine reaches
``min_similarity`` (0.5; docs/heuristics.md); otherwise it is its own concept. Every
label-list method resolves it the same way, so the outcome is decided before any method
reads the map. This benchmark sorts each description into one of three cases and
reports, from the runs of ``bench_quality.py``, what each method's answer was in each:

- *right*: resolved to its ground-truth label;
- *wrong*: resolved to another label;
- *unresolved*: no name within ``min_similarity``.

Part 1 (text only) counts the cases for the free text of each class table, for the absent
free text (resolved to any label, and to one present in the scene), and, with
``--descriptions``, for a list of descriptions of your own; ``--lead FLOOR:LEAD`` adds a
rule that also resolves an unresolved description when its nearest label's cosine is at
least ``FLOOR`` and leads the next label's by ``LEAD`` (tried, not shipped:
docs/benchmarks.md). Part 2 needs the open-list runs of ``bench_quality.py``::

    .venv/bin/python benchmarks/bench_resolve.py --out bench-quality --seeds 0,1,2,3,4 \\
        --descriptions benchmarks/descriptions_selection.yaml --lead 0.45:0.10

It writes ``DIR/resolve.md`` and ``DIR/resolve.json``. A generator whose runs are missing
is run through ``bench_quality.run_one`` first (minutes a scene).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import yaml
from bench_quality import GENERATORS, free_texts, named_generators, parse_seeds, run_one

from quash_plugins.core import registry
from quash_plugins.core.interfaces import ExpansionContext
from quash_plugins.demo.scene import class_set
from quash_plugins.engine import open_cache
from quash_plugins.heuristics import TaxonomyHeuristic

#: The label-list methods of the open-list runs, the chosen one first
METHODS = ("quash-labels", "vlmaps-labels", "openscene-labels")
CASES = ("right", "wrong", "unresolved")


def resolve(
    texts: dict[str, str | None],
    taxonomy: dict,
    encoder,
    cache,
    lead: tuple[float, float] | None = None,
) -> dict[str, dict]:
    """``{text: {"truth", "to", "how", "cosine", "lead", "case"}}`` for each description
    (``truth`` None: an absent object; ``cosine`` and ``lead`` None when it resolved by
    name). ``to`` is what the shipped ``taxonomy`` heuristic
    resolves it to; with ``lead`` (``(floor, lead)``), an unresolved text also resolves
    to its nearest label when that label's cosine is at least ``floor`` and leads the
    next label's by ``lead``."""
    h = TaxonomyHeuristic(taxonomy=taxonomy)
    ctx = ExpansionContext(encoder=encoder, extra={"cache": cache})
    out = {}
    for text, truth in texts.items():
        # the record of an embedding resolution (rules 5 and 6) holds the nearest label's
        # cosine and the next label's; a resolution by name holds neither
        r = h.resolve_query(text, ctx)
        cos, nxt = r.get("cosine"), r.get("next_cosine")
        gap = None if cos is None else (cos - nxt if nxt is not None else np.inf)
        to, how = r["to"], r["how"]
        if how == "none" and lead is not None and cos >= lead[0] and gap >= lead[1]:
            to, how = r["nearest"], "lead"
        case = "unresolved" if to is None else ("right" if to == truth else "wrong")
        out[text] = {
            "truth": truth,
            "to": to,
            "how": how,
            "cosine": cos,
            "lead": None if gap is None else round(float(gap), 4),
            "case": case,
        }
    return out


def counts(res: dict[str, dict], present: set[str] | None = None) -> dict[str, int]:
    """Cases of the present descriptions, and absent ones resolved (to a present label:
    ``present`` given)."""
    c = {case: 0 for case in CASES}
    c.update(absent=0, absent_resolved=0, absent_to_present=0)
    for r in res.values():
        if r["truth"] is None:
            c["absent"] += 1
            c["absent_resolved"] += r["to"] is not None
            c["absent_to_present"] += present is not None and r["to"] in present
        else:
            c[r["case"]] += 1
    return c


def by_case(runs: list[dict], res: dict[str, dict]) -> dict[str, dict[str, dict]]:
    """From open-list runs: per method and case, the mean F1 and the empty answers of the
    present descriptions (``{method: {case: {"f1", "empty", "n"}}}``)."""
    out: dict[str, dict[str, dict]] = {}
    for method in METHODS:
        f1: dict[str, list[float]] = {case: [] for case in CASES}
        empty = dict.fromkeys(CASES, 0)
        for rec in runs:
            for c in rec["configs"]:
                if c["name"] != method:
                    continue
                for q, v in c["per_query"].items():
                    r = res.get(q)
                    if r is None or r["truth"] is None:
                        continue
                    f1[r["case"]].append(v["f1"])
                    empty[r["case"]] += v["n_pred"] == 0
        out[method] = {
            case: {
                "f1": float(np.mean(f1[case])) if f1[case] else None,
                "empty": empty[case],
                "n": len(f1[case]),
            }
            for case in CASES
        }
    return out


def _taxonomy_of(out: Path, gen: str, seed: int) -> tuple[dict, set[str]]:
    stem = out / "scenes" / f"{gen}-seed{seed}"
    tax = yaml.safe_load(Path(f"{stem}.taxonomy.yaml").read_text(encoding="utf-8"))
    present = yaml.safe_load(Path(f"{stem}.queries.yaml").read_text(encoding="utf-8"))
    return tax, set(present["present"])


def _descriptions(gen: str) -> dict[str, str | None]:
    cs = class_set(GENERATORS[gen].get("classes", "a"))
    texts: dict[str, str | None] = {t: label for label, t in cs.free_text.items()}
    texts.update({t: None for t in cs.absent_free_text_open})
    assert set(texts) == set(free_texts(gen))
    return texts


def _own(path: Path, table: str, tax: dict) -> dict[str, str | None]:
    """A descriptions file: ``{a: {label: text}, b: {...}, absent: [text, ...]}``; a table's
    descriptions of labels that its taxonomy lacks are left out."""
    data = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    texts: dict[str, str | None] = {}
    for t in ("a", "b"):
        for label, text in (data.get(t) or {}).items():
            if label in tax and (t == table or text not in texts):
                texts[str(text)] = label
    texts.update({str(t): None for t in data.get("absent") or []})
    return texts


def _row(name: str, c: dict[str, int]) -> str:
    n = sum(c[k] for k in CASES)
    return (
        f"| {name} | {n} | {c['right']} | {c['wrong']} | {c['unresolved']} | "
        f"{c['absent_resolved']}/{c['absent']} | {c['absent_to_present']}/{c['absent']} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-quality", help="bench_quality.py's folder")
    ap.add_argument("--seeds", default="0,1,2,3,4")
    ap.add_argument("--generators", default=None, help="comma-separated (default: all)")
    ap.add_argument("--descriptions", type=Path, help="a YAML file of descriptions of your own")
    ap.add_argument("--lead", help="FLOOR:LEAD, the rule tried and not shipped")
    args = ap.parse_args()
    out = Path(args.out)
    seeds = parse_seeds(args.seeds)
    gens = named_generators(args.generators, None)
    if bad := [g for g in gens if g not in GENERATORS]:
        raise SystemExit(f"unknown generator: {bad[0]} (known: {', '.join(GENERATORS)})")
    lead = None
    if args.lead:
        try:
            floor, gap = (float(x) for x in args.lead.split(":"))
        except ValueError:
            raise SystemExit(f"--lead {args.lead!r}: give FLOOR:LEAD, e.g. 0.45:0.10") from None
        lead = (floor, gap)
    encoder, cache = registry.create("encoders", "minilm"), open_cache(True)
    head = [
        "| descriptions | present | right | wrong | unresolved | absent resolved | "
        "absent to a present label |",
        "|---|---|---|---|---|---|---|",
    ]
    md = [
        "# Free text: how descriptions resolve",
        "",
        "Resolved as every label-list method resolves them (`min_similarity` 0.5).",
        "*right*: to the ground-truth label; *wrong*: to another; *unresolved*: no name",
        "within 0.5. *absent*: descriptions of objects that no scene holds.",
        "",
        *head,
    ]
    summary: dict = {"text": {}, "maps": {}}
    tables_done: set[str] = set()
    answers: list[str] = []
    for gen in gens:
        table = GENERATORS[gen].get("classes", "a")
        runs = [run_one(out, gen, s, "open-list", encoder, cache) for s in seeds]
        tax, present = _taxonomy_of(out, gen, seeds[0])
        reported = _descriptions(gen)
        res = resolve(reported, tax, encoder, cache)
        if table not in tables_done:
            tables_done.add(table)
            rules = [("shipped", None)] + ([(f"lead {args.lead}", lead)] if lead else [])
            sets = [("reported", reported)]
            if args.descriptions:
                sets.append((args.descriptions.name, _own(args.descriptions, table, tax)))
            for set_name, texts in sets:
                for rule_name, rule in rules:
                    reused = set_name == "reported" and rule is None
                    c = counts(
                        res if reused else resolve(texts, tax, encoder, cache, rule), present
                    )
                    summary["text"][f"{table}|{set_name}|{rule_name}"] = c
                    md.append(_row(f"table {table.upper()}, {set_name}, {rule_name}", c))
        cases = by_case(runs, res)
        summary["maps"][gen] = cases
        for method, row in cases.items():
            cells = " | ".join(
                f"{v['f1']:.3f} ({v['empty']}/{v['n']} empty)" if v["n"] else "-"
                for v in row.values()
            )
            answers.append(f"| {gen} | {method} | {cells} |")
        print(f"{gen}: {len(runs)} runs read", flush=True)
    md += [
        "",
        f"## What each method answered, by case (reported free text, seeds {args.seeds})",
        "",
        "Mean F1 of the present descriptions and how many answers were empty.",
        "",
        "| generator | method | right | wrong | unresolved |",
        "|---|---|---|---|---|",
        *answers,
    ]
    (out / "resolve.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    (out / "resolve.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    print("\n".join(md))


if __name__ == "__main__":
    main()
