"""Many queries in one call: the text side of ``Quash.query_many``.

``Q`` distinct queries (names from the shipped vocabulary) are answered in one
``query_many`` call on a random ``N x 384`` map with the shipped MiniLM encoder and the
``vocabulary`` heuristic (positives and negatives are vocabulary names, so query sets
share many strings), with the on-disk text-embedding cache on (a fresh, empty one) as in
the default config, or off. Reported: the wall time of the call, the time of its text
side (expand + encode + fit), and the calls into the encoder and the strings they
embedded (the heuristic's own calls, one per query to place the query in the
vocabulary, included).

Run::

    nice python benchmarks/bench_queries.py --queries 1000 --out /tmp/queries.md
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from importlib import resources

import numpy as np


def vocabulary(n: int) -> list[str]:
    text = resources.files("quash_plugins.data").joinpath("vocabulary.txt").read_text()
    words = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    words = list(dict.fromkeys(words))
    if n > len(words):
        raise SystemExit(f"--queries {n}: the vocabulary has {len(words)} names")
    return words[:n]


def run(
    n_queries: int, rows: int, templates: bool, cache: bool, heuristic: str, warm: bool = False
) -> dict:
    from quash_plugins import Quash
    from quash_plugins.core.types import LatentMap

    cfg = {
        "encoder": "minilm",
        "heuristic": heuristic,
        "classifier": "contrast",
        "instances": False,
        "cache": cache,
        "device": "cpu",
    }
    if templates:
        cfg["prompt_templates"] = {"mode": "mean"}
    q = Quash.from_config(cfg)
    calls = {"n": 0, "strings": 0}
    encode = q.encoder.encode_text

    def counting(texts):
        calls["n"] += 1
        calls["strings"] += len(texts)
        return encode(texts)

    q.encoder.encode_text = counting
    q.encoder.encode_text(["warm up"])  # load the model outside the timing
    calls.update(n=0, strings=0)
    rng = np.random.default_rng(0)
    emb = rng.standard_normal((rows, q.encoder.dim), dtype=np.float32)
    lmap = LatentMap(emb / np.linalg.norm(emb, axis=1, keepdims=True))
    texts = vocabulary(n_queries)
    if warm:  # fill the on-disk cache first; time a fresh pipeline that finds everything
        q.query_many(lmap, texts)
        fresh = Quash.from_config(cfg)
        fresh.encoder.encode_text = counting
        q = fresh
        calls.update(n=0, strings=0)
    t0 = time.perf_counter()
    results = q.query_many(lmap, texts)
    total = time.perf_counter() - t0
    text_side = sum(r.timings.get(k, 0.0) for r in results for k in ("expand", "encode", "fit"))
    return {
        "queries": n_queries,
        "total_s": total,
        "text_s": text_side,
        "encoder_calls": calls["n"],
        "strings": calls["strings"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--queries", type=int, nargs="+", default=[1000])
    ap.add_argument("--rows", type=int, default=20000, help="map items")
    ap.add_argument("--heuristic", default="vocabulary")
    ap.add_argument("--templates", action="store_true", help="prompt templates (mean of 63)")
    ap.add_argument("--no-cache", action="store_true", help="text-embedding cache off")
    ap.add_argument(
        "--warm", action="store_true", help="time a second run on the filled cache (no model)"
    )
    ap.add_argument("--out", default=None, help="write the Markdown table here")
    args = ap.parse_args()
    os.environ.setdefault("QUASH_CACHE_DIR", tempfile.mkdtemp(prefix="bench-queries-"))
    rows = []
    for n in args.queries:
        os.environ["QUASH_CACHE_DIR"] = tempfile.mkdtemp(prefix="bench-queries-")
        r = run(n, args.rows, args.templates, not args.no_cache, args.heuristic, args.warm)
        rows.append(r)
        print(r, flush=True)
    md = [
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; map "
        f"{args.rows} x 384, minilm on CPU, heuristic {args.heuristic}, prompt templates "
        f"{'mean (63)' if args.templates else 'off'}, cache "
        f"{'off' if args.no_cache else 'on, filled by a first run' if args.warm else 'on (empty)'}",
        "",
        "| queries | query_many | text side | encoder calls | strings embedded |",
        "|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        md.append(
            f"| {r['queries']} | {r['total_s']:.1f} s | {r['text_s']:.1f} s | "
            f"{r['encoder_calls']} | {r['strings']} |"
        )
    text = "\n".join(md)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
