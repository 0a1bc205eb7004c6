"""Query-quality benchmark: baselines vs QuASH on proxy scenes with fixed seeds.

Re-run with::

    .venv/bin/python benchmarks/bench_quality.py --out bench-quality/ [--seeds 0,1] [--bench]

For each seed it generates the scene (MiniLM, default options), runs ``quash eval`` with
the shipped demo configs on every present label plus the absence queries, and (with
``--bench``) the ablation tables on the first seed. It prints a Markdown summary and writes
``summary.md``, ``eval-seed<S>.json`` and ``bench/``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from quash_plugins.core import registry
from quash_plugins.demo.runner import demo_config_paths
from quash_plugins.demo.scene import SceneOptions, make_scene, write_scene
from quash_plugins.engine import open_cache
from quash_plugins.evaluation.ablations import run_bench
from quash_plugins.evaluation.plot import plot_precision_recall
from quash_plugins.evaluation.report import evaluate, report_markdown

BASELINES = ("vlmaps", "conceptfusion", "lerf")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="bench-quality")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--bench", action="store_true", help="Also run the ablation tables.")
    ap.add_argument("--rooms", type=int, default=5)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    enc = registry.create("encoders", "minilm")
    cache = open_cache(True)
    seeds = [int(s) for s in args.seeds.split(",")]
    rows: dict[str, list[dict]] = {}
    lines = []
    for seed in seeds:
        opts = SceneOptions(seed=seed, rooms=args.rooms)
        paths = write_scene(make_scene(enc, opts, cache), out / f"scene-seed{seed}.npz", opts)
        t = time.perf_counter()
        rep = evaluate(
            paths["map"],
            demo_config_paths(),
            absent=(
                "piano",
                "bathtub",
                "fireplace",
                "bicycle",
                "washing machine",
                "a red sports car",
                "an elephant",
            ),
        )
        dt = time.perf_counter() - t
        (out / f"eval-seed{seed}.json").write_text(json.dumps(rep.to_json(), indent=2))
        plot_precision_recall(
            rep.configs, out / f"eval-seed{seed}.png", title=f"proxy scene seed {seed}"
        )
        lines += [
            f"### Seed {seed}: {len(rep.queries)} labels, {len(rep.absent)} absence "
            f"queries, {rep.configs and len(rep.configs)} configs, {dt:.0f} s",
            "",
            report_markdown(rep.configs, per_query=False),
        ]
        for c in rep.configs:
            rows.setdefault(c["name"], []).append(c)
        if args.bench and seed == seeds[0]:
            run_bench(
                paths["map"],
                str(paths["taxonomy"]),
                out / "bench",
                absent=("piano", "bathtub", "bicycle"),
            )
    mean = []
    for name, cs in rows.items():
        m = {
            k: float(np.mean([c["mean"][k] for c in cs]))
            for k in ("precision", "recall", "f1", "iou")
        }
        ab = float(np.mean([c["absence"]["score"] for c in cs]))
        mean.append({"name": name, "mean": m, "per_query": {}, "absence": {"score": ab}})
    best_base = max(c["mean"]["f1"] for c in mean if c["name"] in BASELINES)
    q = next(c for c in mean if c["name"] == "quash-taxonomy")
    verdict = (
        f"quash-taxonomy F1 / best baseline F1 = {q['mean']['f1'] / best_base:.2f} "
        f"(target >= 1.5); recall {q['mean']['recall']:.3f} (target >= 0.5); absence "
        f"{q['absence']['score']:.3f} vs best baseline "
        f"{max(c['absence']['score'] for c in mean if c['name'] in BASELINES):.3f}"
    )
    summary = [
        "### Mean over seeds " + ", ".join(map(str, seeds)),
        "",
        report_markdown(mean, per_query=False),
        verdict,
        "",
        *lines,
    ]
    (out / "summary.md").write_text("\n".join(summary) + "\n")
    print("\n".join(summary))


if __name__ == "__main__":
    main()
