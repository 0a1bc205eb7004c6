"""What the presence check's ``reseed`` costs: ``query_many`` with and without it.

``presence.reseed`` (on by default; docs/evaluation.md) runs one more presence check on the
first pass's mask for every refined query whose check finds nothing (every absent query
among them), and, for the queries where an object passes there, one more shared pass over
the map. This runs a scene's closed-vocabulary queries (present and absent labels) through
``demo:quash-labels`` with ``reseed`` off and on (as shipped: with its smaller-object check,
``reseed_min_component``), alternating, ``--repeats`` times each, in
the same process, and reports the median wall time of each and their ratio (the machines
are shared, so only the ratio within a run means much)::

    .venv/bin/python benchmarks/bench_reseed.py --out bench-quality \\
        --scenes low-noise:0,b-hard:0

A scene is built with ``bench_quality.scene`` when ``--out`` does not hold it yet.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import yaml
from bench_quality import GENERATORS, scene

from quash_plugins import Quash
from quash_plugins.core import registry
from quash_plugins.core.shipped import find_shipped
from quash_plugins.engine import open_cache


def quash(taxonomy: Path, reseed: bool) -> Quash:
    """``demo:quash-labels`` given the scene's taxonomy, with ``reseed`` as asked."""
    cfg = find_shipped("demo:quash-labels").data()
    cfg["heuristic"] = {**cfg["heuristic"], "file": str(taxonomy)}
    cfg["presence"] = {**cfg["presence"], "reseed": reseed}
    return Quash.from_config(cfg)


def closed_queries(stem: Path) -> list[str]:
    """The scene's present labels, then its taxonomy's absent ones."""
    info = yaml.safe_load(Path(f"{stem}.queries.yaml").read_text(encoding="utf-8"))
    tax = yaml.safe_load(Path(f"{stem}.taxonomy.yaml").read_text(encoding="utf-8"))
    present = list(info["present"])
    return present + [t for t in tax if t not in present]


def measure(path: Path, repeats: int) -> dict:
    stem = path.with_suffix("")
    queries = closed_queries(stem)
    runs = {on: quash(Path(f"{stem}.taxonomy.yaml"), on) for on in (False, True)}
    for q in runs.values():
        q.query_many(str(path), queries[:2])  # warm: the encoder, the map, the topology
    seconds: dict[bool, list[float]] = {False: [], True: []}
    reseeded = 0
    for _ in range(repeats):
        for on, q in runs.items():
            t = time.perf_counter()
            results = q.query_many(str(path), queries)
            seconds[on].append(time.perf_counter() - t)
            if on:
                reseeded = sum(
                    1
                    for r in results
                    if (r.queryset.provenance.get("presence") or {})
                    .get("reseed", {})
                    .get("positives")
                )
    off, on = statistics.median(seconds[False]), statistics.median(seconds[True])
    return {"queries": len(queries), "off": off, "on": on, "reseeded": reseeded}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-quality", help="folder of the scenes")
    ap.add_argument("--scenes", default="low-noise:0,b-hard:0", help="GENERATOR:SEED,...")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    encoder, cache = registry.create("encoders", "minilm"), open_cache(True)
    print("| scene | queries | reseeded | without (s) | with (s) | ratio |")
    print("|---|---|---|---|---|---|")
    for item in args.scenes.split(","):
        gen, _, seed = item.partition(":")
        if gen not in GENERATORS:
            raise SystemExit(f"unknown generator {gen!r}; known: {', '.join(GENERATORS)}")
        path = scene(Path(args.out), gen, int(seed or 0), encoder, cache)
        m = measure(path, args.repeats)
        print(
            f"| {gen} seed {seed or 0} | {m['queries']} | {m['reseeded']} | {m['off']:.2f} | "
            f"{m['on']:.2f} | {m['on'] / m['off']:.2f}x |",
            flush=True,
        )


if __name__ == "__main__":
    main()
