"""The shipped method at other voxel sizes: do count-based defaults carry over?

The presence check counts items (``min_component: 8``, ``reseed_min_component: 4``) and
refinement draws a number of them (``n_positives: 100``); every default was chosen on
``quash make-scene``'s 0.1 m voxels. VLMaps' own maps use 0.05 m cells, and a coarse map
may use 0.2 m. This benchmark builds the same scene at several voxel sizes (the same
rooms and objects; an object has about four times as many surface voxels at half the
size) and runs the closed and open-list scenarios of ``bench_quality.py`` on it with
QuASH (``quash-labels``) and the two fair peers given the same label list.

Re-run with::

    .venv/bin/python benchmarks/bench_voxel_size.py --out bench-voxel --seeds 0,1

(``--voxel-sizes 0.05,0.1,0.2`` and ``--rooms 2`` by default: a 0.05 m scene of five
rooms has ~200k voxels). It writes ``DIR/voxel.md`` and ``DIR/voxel.json``; finished
runs are reused from ``DIR/runs``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from bench_quality import configs, parse_seeds, queries

from quash_plugins.core import registry
from quash_plugins.demo.scene import SceneOptions, make_scene, write_scene
from quash_plugins.engine import open_cache
from quash_plugins.evaluation.report import evaluate

METHODS = ("quash-labels", "vlmaps-labels", "openscene-labels")
SCENARIOS = ("closed", "open-list")


def parse_sizes(spec: str) -> list[float]:
    """The voxel sizes of ``--voxel-sizes``: comma-separated positive metres."""
    try:
        sizes = [float(s) for s in spec.split(",") if s]
    except ValueError:
        sizes = []
    if not sizes or any(not np.isfinite(s) or s <= 0 for s in sizes):
        raise SystemExit(f"--voxel-sizes {spec!r}: give positive metres, e.g. 0.05,0.1,0.2")
    return sizes


def run(out: Path, seed: int, size: float, rooms: int, scenario: str, encoder, cache) -> dict:
    """One scene and scenario through ``evaluate`` with the label-list methods; cached."""
    stem = f"seed{seed}-v{size:g}-r{rooms}"
    res = out / "runs" / f"{stem}-{scenario}.json"
    if res.exists():
        return json.loads(res.read_text(encoding="utf-8"))
    path = out / "scenes" / f"{stem}.npz"
    if not path.exists():
        opts = SceneOptions(seed=seed, rooms=rooms, voxel_size=size)
        write_scene(make_scene(encoder, opts, cache), path, opts)
    present, absent = queries(path, scenario)
    taxonomy = Path(f"{path.with_suffix('')}.taxonomy.yaml")
    cfgs = [c for c in configs(scenario, taxonomy) if c["name"] in METHODS]
    t = time.perf_counter()
    rep = evaluate(str(path), cfgs, queries=present, absent=absent)
    n_items = int(np.load(path)["embeddings"].shape[0])
    rec = {
        "seed": seed,
        "voxel_size": size,
        "rooms": rooms,
        "scenario": scenario,
        "items": n_items,
        "seconds": round(time.perf_counter() - t, 1),
        "configs": {
            c["name"]: {
                "f1": c["mean"]["f1"],
                "recall": c["mean"]["recall"],
                "ap": c["mean"]["ap"],
                "absence": c["absence"]["score"],
                "present_empty": c["absence"].get("present_empty", 0),
                "n_present": len(c["per_query"]),
                "given": c.get("given", ""),
            }
            for c in rep.configs
        },
    }
    res.parent.mkdir(parents=True, exist_ok=True)
    res.write_text(json.dumps(rec) + "\n", encoding="utf-8")
    return rec


def summary(recs: list[dict]) -> list[str]:
    """One Markdown table: per scenario and voxel size, each method's means over seeds,
    and QuASH's F1 over the better fair peer's."""
    lines = [
        "| scenario | voxel size | items (mean) | method | F1 | recall | AP | absence | "
        "present -> empty | F1 / best fair peer |",
        "|---|---|---:|---|---:|---:|---:|---:|---:|---:|",
    ]
    for scenario in SCENARIOS:
        for size in sorted({r["voxel_size"] for r in recs}):
            group = [r for r in recs if r["scenario"] == scenario and r["voxel_size"] == size]
            if not group:
                continue
            items = int(np.mean([r["items"] for r in group]))
            mean = {
                m: {
                    k: float(np.mean([r["configs"][m][k] for r in group]))
                    for k in ("f1", "recall", "ap", "absence")
                }
                for m in METHODS
            }
            peer = max(mean[m]["f1"] for m in METHODS[1:])
            n_present = sum(r["configs"][METHODS[0]]["n_present"] for r in group)
            for m in METHODS:
                empty = sum(r["configs"][m]["present_empty"] for r in group)
                ratio = f"{mean[m]['f1'] / peer:.2f}x" if m == METHODS[0] and peer else ""
                lines.append(
                    f"| {scenario} | {size:g} m | {items} | {m} | {mean[m]['f1']:.3f} | "
                    f"{mean[m]['recall']:.3f} | {mean[m]['ap']:.3f} | {mean[m]['absence']:.3f} | "
                    f"{empty}/{n_present} | {ratio} |"
                )
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("bench-voxel"))
    ap.add_argument("--seeds", default="0,1", help="scene seeds (default: 0,1)")
    ap.add_argument("--voxel-sizes", default="0.05,0.1,0.2", help="metres (comma-separated)")
    ap.add_argument("--rooms", type=int, default=2, help="rooms per scene (default: 2)")
    args = ap.parse_args()
    seeds, sizes = parse_seeds(args.seeds), parse_sizes(args.voxel_sizes)
    if args.rooms < 1:
        raise SystemExit(f"--rooms {args.rooms}: give at least 1")
    encoder = registry.create("encoders", "minilm")
    cache = open_cache(True)
    recs = []
    jobs = [(s, v, sc) for s in seeds for v in sizes for sc in SCENARIOS]
    for i, (seed, size, scenario) in enumerate(jobs, 1):
        print(f"[{i}/{len(jobs)}] seed {seed}, {size:g} m, {scenario}", flush=True)
        recs.append(run(args.out, seed, size, args.rooms, scenario, encoder, cache))
    lines = [
        f"Seeds {args.seeds}, {args.rooms} rooms; means over seeds; present -> empty summed.",
        "",
        *summary(recs),
    ]
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "voxel.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    (args.out / "voxel.json").write_text(json.dumps(recs, indent=1) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
